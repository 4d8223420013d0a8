"""Drawing, for any robot: the paper's Fig. 1 (:mod:`~firmtool.figures.paths`: a roadmap, its
policies and executed episodes; ``ft.plot``) and the calibration plot (:mod:`~firmtool.figures.calibration`).

Only drawing lives here: the figure kinds that run episodes for a figure are :mod:`firmtool.api.figures`,
the figure files (formats, provenance) :mod:`firmtool.io.figure_file`. (Named ``figures``, not ``plot``:
a submodule ``firmtool.plot`` would replace the function ``firmtool.plot`` as soon as it was imported.)
"""
