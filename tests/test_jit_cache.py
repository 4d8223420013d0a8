"""numba's disk cache and edits of compiled functions in other modules (firmtool.jit).

numba keys a cached function on its own source file only, so a caller whose callee lives in another
module kept running the callee's old machine code after an edit of it. These tests compile with the
cache, edit the callee's source, and run again in a fresh process: the new behaviour must run. Each
first checks that the unchanged second run did load from the cache (else a stale result could not
happen and the check would prove nothing).
"""

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

numba = pytest.importorskip("numba")

from firmtool import jit as _jit  # noqa: E402
from firmtool.estimation import compiled as kernels
from firmtool.estimation.compiled import rng
from firmtool.robots import planar

ROOT = Path(__file__).resolve().parents[1]


def _run(code: str, path: Path, cache: Path) -> dict:
    """``code`` in a fresh interpreter with ``path`` first on sys.path and numba's cache in ``cache``;
    returns the JSON it prints last."""
    env = dict(os.environ, PYTHONPATH=str(path), NUMBA_CACHE_DIR=str(cache))
    env.pop("NUMBA_DISABLE_JIT", None)
    out = subprocess.run([sys.executable, "-c", code], cwd=path, env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert text.count(old) == 1, f"{path.name}: the text to edit is not there once: {old!r}"
    path.write_text(text.replace(old, new))


# A package of three modules: the caller reaches the leaf through a function of a second module,
# which calls it as an attribute of the leaf's module.
PACKAGE = {
    "__init__.py": "",
    "leaf.py": "DECORATOR\n\n@jit\ndef leaf(x):\n    return x + 1.0\n",
    "middle.py": ("DECORATOR\nfrom pkg import leaf as leaf_module\n\n"
                  "@jit\ndef middle(x):\n    return leaf_module.leaf(x) * 2.0\n"),
    "caller.py": "DECORATOR\nfrom pkg.middle import middle\n\n@jit\ndef caller(x):\n    return middle(x) + 100.0\n",
}
DECORATORS = {"firmtool": "from firmtool.jit import cached_njit\njit = cached_njit()",
              "numba": "import numba\njit = numba.njit(cache=True)"}
CALL = ("import json\nfrom pkg.caller import caller\nv = caller(1.0)\n"
        "print(json.dumps({'value': v, 'hits': sum(caller.stats.cache_hits.values())}))")


@pytest.mark.parametrize("decorator", ["firmtool", "numba"])
def test_a_callees_edit_in_another_module_is_compiled_not_loaded_stale(tmp_path, decorator):
    pkg = tmp_path / "src" / "pkg"
    pkg.mkdir(parents=True)
    for name, text in PACKAGE.items():
        (pkg / name).write_text(text.replace("DECORATOR", DECORATORS[decorator]))
    src, cache = tmp_path / "src", tmp_path / "cache"
    first = _run(CALL, src, cache)
    second = _run(CALL, src, cache)
    assert first == {"value": 104.0, "hits": 0} and second == {"value": 104.0, "hits": 1}  # compiled, then loaded
    _edit(pkg / "leaf.py", "x + 1.0", "x + 2.0")
    edited = _run(CALL, src, cache)["value"]
    if decorator == "firmtool":
        assert edited == 106.0
    else:  # the trap itself, with numba's own cache: if this fails, numba now tracks callees (issue #1833)
        assert edited == 104.0, "numba's cache noticed the callee's edit: firmtool.jit may no longer be needed"


KERNEL_CALLS = textwrap.dedent("""
    import json
    import numpy as np
    import firmtool
    from firmtool.estimation.compiled import collide, step
    assert firmtool.__file__.startswith({root!r}), firmtool.__file__
    # the control through linalg.mat_rows: U = u_ref - K (XH - x_ref)
    XH, DX, U = np.array([[1.0, 2.0], [3.0, 4.0]]), np.empty((2, 2)), np.empty((1, 2))
    step.control(XH, np.zeros(2), np.zeros(1), np.array([[1.0, 1.0]]), DX, U, 2)
    # a disc of radius 0.1 at (0.38, 0.38), 0.113 from the corner of the box [-0.3, 0.3]^2: its
    # bounding box overlaps the box's, so geometry._numba.seg_box_d2 decides (clear)
    C, Hs = np.zeros((1, 2)), np.full((1, 2), 0.3)
    world = (np.array([-2.0, -2.0]), np.array([2.0, 2.0]), C, Hs, np.ones(1), np.zeros(1), C - Hs, C + Hs, 0.1,
             (np.zeros((0, 0)), np.zeros(7)))
    hit = collide.collides(np.array([0.38]), np.array([0.38]), 1, 0, world, False, np.zeros(0))
    hits = sum(sum(f.stats.cache_hits.values()) for f in (step.control, collide.collides))
    print(json.dumps({{"control": U.tolist(), "collides": bool(hit), "hits": hits}}))
""")


def test_the_kernels_cache_notices_edits_of_the_controllers_and_the_geometry(tmp_path):
    """The real case: in a copy of the package, the kernel's control (which calls control.linalg.mat_rows)
    and collision test (geometry._numba.seg_box_d2) compiled and cached, those two callees edited,
    then run again in a fresh process."""
    src, cache = tmp_path / "src", tmp_path / "cache"
    shutil.copytree(ROOT / "firmtool", src / "firmtool", ignore=shutil.ignore_patterns("__pycache__"))
    code = KERNEL_CALLS.format(root=str(src))
    first = _run(code, src, cache)
    second = _run(code, src, cache)
    assert first["control"] == [[-4.0, -6.0]] and first["collides"] is False and first["hits"] == 0
    assert second["hits"] == 2 and second["control"] == first["control"] and second["collides"] is False
    _edit(src / "firmtool" / "control" / "linalg.py", "out[i, c] += a * B[l, c]", "out[i, c] += 2.0 * a * B[l, c]")
    nearest_corner = "d = min(pbox_d2(ax, ay, hx, hy), pbox_d2(bx, by, hx, hy))"  # seg_box_d2: now always 0
    _edit(src / "firmtool" / "geometry" / "_numba.py", nearest_corner, nearest_corner.replace("= min", "= 0.0 * min"))
    edited = _run(code, src, cache)
    assert edited["control"] == [[-8.0, -12.0]] and edited["collides"] is True


def test_the_kernels_cache_key_covers_every_module_it_calls_into():
    run = kernels.kernel(planar.point_kinematics(1))  # the point robot's kernel: its hooks are callees too
    engine = {f"firmtool.estimation.compiled.{m}" for m in ("run", "bindings", "step", "model", "rng", "collide", "goal", "maps")}
    others = {"firmtool.roadmap.membership", "firmtool.control.linalg", "firmtool.geometry._numba",
              "firmtool.robots.planar", "firmtool.models.angles"}  # angles: stream 2's sincos (compiled.rng)
    assert set(_jit.dependency_files(run.py_func)) == engine | others
    assert set(_jit.dependency_files(rng.fill_normals.py_func)) == {"firmtool.estimation.compiled.rng"}


# Two specialisations of one function (the kernel against two robots' hooks): one index file, two keys.
HOOKED = {
    "__init__.py": "",
    "hooks.py": ("from firmtool.jit import cached_njit\njit = cached_njit()\n\n"
                 "@jit\ndef plus_one(x):\n    return x + 1.0\n\n@jit\ndef times_three(x):\n    return x * 3.0\n"),
    "kern.py": ("hook = None  # bound per specialisation\n\n"
                "def total(x):\n    s = 0.0\n    for i in range(x.shape[0]):\n        s += hook(x[i])\n    return s\n"),
}
HOOKED_CALL = """
import json
import numpy as np
from firmtool.jit import specialise
from pkg import hooks, kern
out = {}
for name in ("plus_one", "times_three"):
    f = specialise(kern.total, {"hook": getattr(hooks, name)}, {})
    out[name] = [f(np.arange(3.0)), sum(f.stats.cache_hits.values()), sum(f.stats.cache_misses.values())]
print(json.dumps(out))
"""


def test_two_specialisations_share_one_index_file_under_two_keys(tmp_path):
    """firmtool.jit.specialise: the second process loads both specialisations from the cache (hits, no
    misses), each its own code (with numba's key alone the second would load the first's: 6.0)."""
    pkg = tmp_path / "src" / "pkg"
    pkg.mkdir(parents=True)
    for name, text in HOOKED.items():
        (pkg / name).write_text(text)
    src, cache = tmp_path / "src", tmp_path / "cache"
    first = _run(HOOKED_CALL, src, cache)
    second = _run(HOOKED_CALL, src, cache)
    assert first == {"plus_one": [6.0, 0, 1], "times_three": [9.0, 0, 1]}
    assert second == {"plus_one": [6.0, 1, 0], "times_three": [9.0, 1, 0]}
    assert len(list(cache.rglob("kern.total-*.nbi"))) == 1 and len(list(cache.rglob("kern.total-*.nbc"))) == 2


# A constant imported from another module (as the kernel imports its outcome codes): numba freezes its value.
CONSTANT = {
    "__init__.py": "",
    "codes.py": "FAILURE = -1\n",
    "caller.py": "DECORATOR\nfrom pkg.codes import FAILURE\n\n@jit\ndef caller(x):\n    return x + FAILURE\n",
}


@pytest.mark.parametrize("decorator", ["firmtool", "numba"])
def test_an_edit_of_an_imported_constant_is_compiled_not_loaded_stale(tmp_path, decorator):
    pkg = tmp_path / "src" / "pkg"
    pkg.mkdir(parents=True)
    for name, text in CONSTANT.items():
        (pkg / name).write_text(text.replace("DECORATOR", DECORATORS[decorator]))
    src, cache = tmp_path / "src", tmp_path / "cache"
    first = _run(CALL, src, cache)
    second = _run(CALL, src, cache)
    assert first == {"value": 0.0, "hits": 0} and second == {"value": 0.0, "hits": 1}  # compiled, then loaded
    _edit(pkg / "codes.py", "FAILURE = -1", "FAILURE = -5")
    edited = _run(CALL, src, cache)["value"]
    if decorator == "firmtool":
        assert edited == -4.0
    else:  # numba's own key holds neither the value nor the file that defines it
        assert edited == 0.0, "numba's cache noticed the constant's edit: firmtool.jit may cover it twice"


def test_the_kernels_key_holds_the_outcome_codes_it_reads():
    """The kernel's key changes with the value of a constant it imports (FAILURE, from
    firmtool.estimation.outcomes), here rebound as specialise binds names; the same value, the same key."""
    from firmtool.estimation.compiled import run as run_module

    run = kernels.kernel(planar.point_kinematics(1))
    rebound = _jit.specialise(run.py_func, {"FAILURE": run_module.FAILURE - 10}, run.targetoptions)
    assert _jit.dependency_digest(run.py_func) != _jit.dependency_digest(rebound.py_func)
    same = _jit.specialise(run.py_func, {"FAILURE": run_module.FAILURE}, run.targetoptions)
    assert _jit.dependency_digest(run.py_func) == _jit.dependency_digest(same.py_func)
