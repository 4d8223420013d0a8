"""Shared helpers of the benchmark suite: roadmaps built once per run, medians, engine switch."""

from __future__ import annotations

import atexit
import contextlib
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = {"arm": ROOT / "scenarios" / "arm8_lightdark.toml", "point": ROOT / "scenarios" / "point_lightdark.toml"}
_TMP = Path(tempfile.mkdtemp(prefix="firmtool-bench-"))
_OWNER = os.getpid()
# removed when the benchmark ends (not by forked workers, which inherit the handler); before, every
# run left a firmtool-bench-* folder behind in the shared temporary folder
atexit.register(lambda: os.getpid() == _OWNER and shutil.rmtree(_TMP, ignore_errors=True))
_designed: dict[str, Path] = {}


def one_blas_thread() -> None:
    """As the CLI does: one BLAS thread (small matrices), scipy's own BLAS loaded first so it is covered."""
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits
    threadpool_limits(1)


def designed_roadmap(name: str) -> Path:
    """The scenario sampled and designed (no edges estimated) into a temporary roadmap file."""
    if name not in _designed:
        from firmtool.pipeline import design_stage, sample_stage
        out = _TMP / f"{name}.h5"
        sample_stage(SCENARIOS[name], out)
        design_stage(out)
        _designed[name] = out
    return _designed[name]


def load(name: str):
    """(problem, design, regions) of a designed roadmap."""
    from firmtool.io.roadmap_file import RoadmapFile
    from firmtool.pipeline import design_of, problem_of
    rm = RoadmapFile(designed_roadmap(name))
    problem, d = problem_of(rm), design_of(rm)
    return problem, d, d.regions(problem)


@contextlib.contextmanager
def engine(name: str | None):
    """Set FIRMTOOL_ENGINE for this process and the workers it forks."""
    old = os.environ.get("FIRMTOOL_ENGINE")
    if name is None:
        os.environ.pop("FIRMTOOL_ENGINE", None)
    else:
        os.environ["FIRMTOOL_ENGINE"] = name
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("FIRMTOOL_ENGINE", None)
        else:
            os.environ["FIRMTOOL_ENGINE"] = old


def median_of(fn, repeat: int) -> tuple[float, list[float]]:
    values = [fn() for _ in range(repeat)]
    return statistics.median(values), values


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def machine() -> dict:
    import platform
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    mem = None
    with contextlib.suppress(OSError, ValueError, IndexError):
        mem = round(int(Path("/proc/meminfo").read_text().split()[1]) / 2**20, 1)
    cpu = platform.processor()
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    import numba
    import numpy
    return {"cores": cores, "memory_gib": mem, "cpu": cpu, "python": platform.python_version(),
            "numpy": numpy.__version__, "numba": numba.__version__}
