"""The ground floor below the file formats: values checked and identified, and the process's Ctrl-C.

The API's arguments checked at entry (:mod:`~firmtool.util.arguments`), the declarative field schema a
scenario's sections and a robot's ``[model]`` keys are read with (:mod:`~firmtool.util.schema`), hashes
of values (:mod:`~firmtool.util.hashing`), fingerprints of a user's code (:mod:`~firmtool.util.fingerprint`)
and the command line's Ctrl-C handling (:mod:`~firmtool.util.interrupts`). None of them reads or writes
a file; they import nothing of firmtool but its errors.
"""
