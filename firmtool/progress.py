"""Progress of long stages: the library calls a callback, the caller decides what to show.

Every stage that can take more than a second (sampling nodes, designing stabilisers and edges,
estimating edges, solving, running episodes, plotting) accepts ``progress``, a callable::

    progress(stage: str, done: int, total: int) -> None

called with ``done = 0`` when the stage starts, then as units finish (nodes, edges, episodes...), and
with ``done = total`` when it ends. ``stage`` is one of the names below; ``total`` may change between
calls of one stage (e.g. bridge nodes added to a roadmap). The library never prints: the command
line draws a progress bar on a terminal and nothing in CI; a notebook may pass its own callback::

    def show(stage, done, total):
        print(f"\\r{stage}: {done}/{total}", end="")

    rm = ft.build(sc, progress=show)

A callback must be cheap (it runs in the stage's loop) and must not raise.
"""

from __future__ import annotations

from typing import Callable, Optional

#: ``progress(stage, done, total)``: see the module docs.
ProgressCallback = Callable[[str, int, int], None]

SAMPLE = "sample"  # nodes sampled (of the requested count, growing with bridge nodes)
DESIGN_NODES = "design: node stabilisers"  # node stabilisers designed
DESIGN_EDGES = "design: edges"  # neighbour pairs checked and nominal trajectories computed
ESTIMATE = "estimate"  # edges estimated by Monte Carlo
SOLVE = "solve"  # steps of the solve (the DP, success probabilities, the baseline)
EXECUTE = "execute"  # episodes run
PLOT = "plot"  # episodes run for a figure, then the figure drawn

STAGES = (SAMPLE, DESIGN_NODES, DESIGN_EDGES, ESTIMATE, SOLVE, EXECUTE, PLOT)


def report(progress: Optional[ProgressCallback], stage: str, done: int, total: int) -> None:
    """Call ``progress`` if there is one (the one line every stage uses)."""
    if progress is not None:
        progress(stage, int(done), int(total))


class Counter:
    """Counts the units of one stage and reports them: ``start()``, ``advance(n)``, ``finish()``.

    Parameters
    ----------
    progress : the callback, or None (then every call is a no-op).
    stage : the stage's name.
    total : units the stage will do.
    """

    def __init__(self, progress: Optional[ProgressCallback], stage: str, total: int) -> None:
        self.progress, self.stage, self.total, self.done = progress, stage, int(total), 0

    def start(self) -> "Counter":
        report(self.progress, self.stage, 0, self.total)
        return self

    def advance(self, n: int = 1) -> None:
        self.done += int(n)
        report(self.progress, self.stage, min(self.done, self.total), self.total)

    def finish(self) -> None:
        self.done = self.total
        report(self.progress, self.stage, self.total, self.total)

    def callback(self) -> Callable[[int], None]:
        """``advance`` as a plain function of the units finished (for code that takes one)."""
        return self.advance


# What to call when a background compile of the Monte Carlo engine starts (firmtool.estimation.warmup
# reads it; the command line sets it). Held here, not in warmup, so that setting it imports no numba:
# every command sets it, and check, inspect or solve never compile (1.3 s of start-up; issue 54).
_compile_notifier: Optional[Callable[[str], None]] = None


def set_compile_notifier(callback: Optional[Callable[[str], None]]) -> None:
    """Call ``callback(kind)`` (once, from a helper thread) when a background compile starts compiling;
    ``kind``: ``"planar"`` or ``"3-D"`` (which kernel: their compile times differ several-fold)."""
    global _compile_notifier
    _compile_notifier = callback


def compile_notifier() -> Optional[Callable[[str], None]]:
    """The callback :func:`set_compile_notifier` set (None: none)."""
    return _compile_notifier

