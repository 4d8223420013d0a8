"""Reference roadmaps: digests of every stored array of the shipped scenarios' roadmaps (issue 34).

The package's redesign (issue 34) must change no number: the same scenario and seed give the same
nodes, controllers, edge tables and policies, bit for bit. This module builds and solves roadmaps
through the public API only (``ft.load_scenario``, ``ft.build``, ``ft.solve``, ``Solution.save``),
so that it runs on any checkout, and records per dataset of ``/nodes``, ``/controllers``, ``/edges``
and ``/policy`` its dtype, shape and the sha256 of its bytes, plus the stages' numeric attributes.
``tests/test_tables_unchanged.py`` compares the current code with the reference.

Two sets, both written on main at 4071a87 (before the redesign):

- ``reduced``: every shipped scenario with few nodes and particles (a build of seconds), for the
  suite;
- ``shipped``: the shipped scenarios as they ship (minutes on 2 cores), for ``pytest -m slow``.

Regenerate (only when a change of numbers is intended, and say why in the commit), with the BLAS
kernels the reference was recorded with (tests/test_tables_unchanged.py says why)::

    OPENBLAS_CORETYPE=Haswell python tests/data/reference_tables.py [reduced|shipped]

``--rounded [reduced|shipped]`` re-digests only the machine-dependent datasets (:data:`ROUNDED`),
checking that everything else is reproduced bit for bit.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FIXTURE = HERE / "reference_tables.json"
# the same roadmaps drawn with stream 2 (issue 55's counter-based stream, new roadmaps' default), recorded
# with ``python tests/data/reference_tables.py --stream2 reduced`` (tests/test_tables_stream2.py)
FIXTURE_STREAM2 = HERE / "reference_tables_stream2.json"

SCENARIOS = ("smoke", "point_lightdark", "point_perfect", "platt_lightdark", "maze_lightdark",
             "unicycle_lightdark", "unicycle_perfect", "arm8_lightdark")

# few nodes and particles: every scenario's build in seconds, every stage and engine still exercised
REDUCED = {"roadmap": {"nodes": 14}, "estimation": {"particles": 40}}
GROUPS = ("nodes", "controllers", "edges", "policy")


def scenario(name: str, kind: str):
    import firmtool as ft

    sc = ft.load_scenario(name)
    if kind == "reduced":
        sc = sc.replace(**REDUCED)
    return sc


def _attr(value):
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, str):
        return value
    a = np.asarray(value)
    if a.dtype.kind in "fiub":
        return [float(v) for v in a.ravel()]
    return str(value)


# attributes that name times, versions or the file, not numbers of the roadmap
VOLATILE = ("created", "firmtool_version", "seconds", "time", "elapsed", "wall", "path", "source")


# Datasets whose last bits depend on the machine: the cost terms' means and covariances (and the
# costs and cost-to-go weighted from them) are sums of the particles' control effort and of filter
# covariances, computed through BLAS and SIMD reductions whose rounding differs between CPU kinds
# (found: an AMD EPYC and the machine that recorded the reference agree on every other dataset, the
# outcome counts and the policy included, and differ there in the last bits). They are digested
# rounded to 6 significant digits: a rounding boundary lies within a few ulps of a value with
# probability ~1e-10, while a change of what is computed moves them far more.
ROUNDED = {("edges", "cost_terms_mean"), ("edges", "cost_terms_cov"), ("edges", "cost_mean"), ("edges", "cost_std"),
           ("policy", "cost_to_go")}
ROUNDED_DIGITS = 6


def rounded_digest(arr: np.ndarray) -> str:
    """sha256 of the values of ``arr`` written with :data:`ROUNDED_DIGITS` significant digits."""
    text = ",".join(f"{v:.{ROUNDED_DIGITS - 1}e}" for v in np.asarray(arr, dtype=float).ravel())
    return f"rounded{ROUNDED_DIGITS}:" + hashlib.sha256(text.encode()).hexdigest()


def digests(path: Path) -> dict:
    """Per dataset of the stage groups: dtype, shape and sha256 of its bytes (of its values rounded,
    for the :data:`ROUNDED` ones); per group its attributes."""
    import h5py

    out: dict = {}
    with h5py.File(path, "r") as f:
        for group in GROUPS:
            if group not in f:
                continue
            g = f[group]
            entry: dict = {"attrs": {k: _attr(v) for k, v in sorted(g.attrs.items())
                                     if not any(w in k for w in VOLATILE)}, "datasets": {}}

            def visit(name, obj, entry=entry, group=group):
                if isinstance(obj, h5py.Dataset):
                    arr = np.asarray(obj[()])
                    digest = rounded_digest(arr) if (group, name) in ROUNDED else \
                        hashlib.sha256(np.ascontiguousarray(arr).tobytes()).hexdigest()
                    entry["datasets"][name] = [str(arr.dtype), list(arr.shape), digest]

            g.visititems(visit)
            out[group] = entry
    return out


# Scenarios whose reference was built by the numpy Monte Carlo engine, the only one their robot had
# then: the unicycle's compiled engine (issue 55) draws its own noise, so it is held to the numpy engine
# particle by particle (tests/test_landmarks.py), and these references keep checking the numpy path.
NUMPY_ENGINE = ("unicycle_lightdark", "unicycle_perfect")


def record(name: str, kind: str) -> dict:
    from threadpoolctl import threadpool_limits

    import firmtool as ft

    if name in NUMPY_ENGINE:  # a process of its own (tests/test_tables_unchanged.py): set for its whole run
        os.environ["FIRMTOOL_ENGINE"] = "numpy"
    # the references drew stream 1 (issue 55 made stream 2 new roadmaps' default): pinned without
    # touching the scenario text, whose sha256 every stage records
    os.environ.setdefault("FIRMTOOL_STREAM", "1")
    with threadpool_limits(1), tempfile.TemporaryDirectory() as tmp:
        sol = ft.solve(ft.build(scenario(name, kind), workers=1))
        path = sol.save(Path(tmp) / f"{name}.h5")
        return {"success_probability": float(sol.success_probability), "policy": [int(e) for e in sol.policy],
                "digests": digests(path)}


def redigest_rounded(kinds: list[str]) -> None:
    """Replace the digests of the :data:`ROUNDED` datasets by their rounded digests, after checking
    that every other number of the recorded reference is reproduced here bit for bit (the reference
    itself is not re-recorded)."""
    out = json.loads(FIXTURE.read_text())
    for kind in kinds:
        for name in SCENARIOS:
            got, want = record(name, kind), out[kind][name]
            assert got["policy"] == want["policy"] and got["success_probability"] == want["success_probability"], name
            differ = []
            for group, entry in want["digests"].items():
                if entry["attrs"] != got["digests"][group]["attrs"]:
                    differ.append(f"/{group} attributes")
                for dataset, digest in entry["datasets"].items():
                    mine = got["digests"][group]["datasets"][dataset]
                    if (group, dataset) in ROUNDED:
                        entry["datasets"][dataset] = mine
                    elif mine != digest:
                        differ.append(f"/{group}/{dataset}")
            if differ:
                sys.exit(f"{kind} {name}: not reproduced bit for bit: {', '.join(differ)}; nothing written")
            print(kind, name, "re-digested", file=sys.stderr)
        FIXTURE.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")


def main(kinds: list[str], fixture: Path = FIXTURE) -> None:
    out = json.loads(fixture.read_text()) if fixture.exists() else {}
    for kind in kinds:
        out[kind] = {}
        for name in SCENARIOS:
            out[kind][name] = record(name, kind)
            print(kind, name, out[kind][name]["success_probability"], file=sys.stderr)
            fixture.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--rounded"]:
        redigest_rounded(sys.argv[2:] or ["reduced", "shipped"])
    elif sys.argv[1:2] == ["--stream2"]:  # each scenario in a process of its own, as the test records it
        import subprocess

        env = dict(os.environ, FIRMTOOL_STREAM="2")
        out = {}
        for kind in sys.argv[2:] or ["reduced"]:
            out[kind] = {}
            for name in SCENARIOS:
                code = f"import json, sys; sys.path.insert(0, {str(HERE)!r}); import reference_tables as r; " \
                       f"print(json.dumps(r.record({name!r}, {kind!r})))"
                run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
                out[kind][name] = json.loads(run.stdout.strip().splitlines()[-1])
                print(kind, name, out[kind][name]["success_probability"], file=sys.stderr)
        FIXTURE_STREAM2.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    else:
        main(sys.argv[1:] or ["reduced", "shipped"])
