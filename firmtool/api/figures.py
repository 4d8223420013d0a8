"""Figure kinds (``firmtool plot --kind KIND``): the recipes that run the episodes a figure needs
(:func:`firmtool.api.execution.simulate`) and hand them to the drawing (:mod:`firmtool.figures`).

Not imported by :mod:`firmtool.api` itself: matplotlib's import (~1.9 s) is paid only by a caller
that makes a figure.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from matplotlib.figure import Figure

from firmtool.api.execution import simulate
from firmtool.api.solution import Solution
from firmtool.errors import InputError
from firmtool.estimation.budgets import MAX_EXECUTION_STEPS
from firmtool.estimation.edge_table import ENGINE_VERSION
from firmtool.figures.calibration import calibration_figure
from firmtool.figures.paths import DEFAULT_UNIT, plot_policies
from firmtool.io.figure_file import provenance


@dataclass(frozen=True)
class FigureOptions:
    """What ``firmtool plot`` asks of a figure kind.

    Attributes
    ----------
    episodes : episodes to run per policy (0: none).
    seed : seed of the episodes (as in ``firmtool execute``).
    policies : the policies to draw (``"firm"``, ``"shortest-path"``).
    dpi : resolution.
    unit : length unit of the axes.
    progress : ``progress(stage, done, total)`` (:mod:`firmtool.progress`), or None.
    max_total_steps : the bound of the episodes' worst-case control steps (``--max-total-steps``).
    """

    episodes: int = 20
    seed: int = 0
    policies: tuple[str, ...] = ("firm", "shortest-path")
    dpi: int = 120
    unit: str = DEFAULT_UNIT
    progress: Callable[[str, int, int], None] | None = None
    max_total_steps: float = MAX_EXECUTION_STEPS


def _relabel(progress, stage: str):
    """A progress callback reporting under ``stage`` (episodes run for a figure)."""
    return None if progress is None else (lambda _stage, done, total: progress(stage, done, total))


def paths_figure(solution, options: FigureOptions) -> Figure:
    """The paper's Fig. 1, one panel per policy (:func:`plot_policies`)."""
    results = [simulate(solution, options.episodes, options.seed, policy=name,
                           progress=_relabel(options.progress, f"plot: {name} episodes"),
                           max_total_steps=options.max_total_steps)
               if options.episodes else None for name in options.policies]
    return plot_policies(solution, results, list(options.policies), dpi=options.dpi, unit=options.unit)


def calibration_kind_figure(solution, options: FigureOptions) -> Figure:
    """The calibration plot of the FIRM policy's edges over ``options.episodes`` episodes."""
    results = simulate(solution, max(options.episodes, 1), options.seed, record=False,
                          progress=_relabel(options.progress, "plot: episodes"),
                          max_total_steps=options.max_total_steps)
    return calibration_figure(results, dpi=options.dpi)


FIGURE_KINDS: dict[str, Callable[..., Figure]] = {"paths": paths_figure, "calibration": calibration_kind_figure}


def register_figure(kind: str, make: Callable[..., Figure]) -> None:
    """Add a figure kind to ``firmtool plot --kind``: ``make(solution, options: FigureOptions) -> Figure``
    (a bare matplotlib Figure, saved by :func:`firmtool.io.figure_file.save_figure`). The disturbance sweep and the
    reliability diagram plug in here."""
    FIGURE_KINDS[kind] = make


def make_figure(kind: str, solution, options: FigureOptions) -> Figure:
    """The figure of a kind (:data:`FIGURE_KINDS`) for a solved roadmap."""

    if kind not in FIGURE_KINDS:
        raise InputError(f"--kind: expected one of {', '.join(FIGURE_KINDS)}, found {kind!r}")
    return FIGURE_KINDS[kind](solution, options)


def figure_provenance(solution: Solution, options: FigureOptions | None = None) -> dict[str, str]:
    """What a figure's numbers come from, for its PNG text chunks (:func:`firmtool.io.figure_file.provenance`):
    the scenario's name and the hash of its text, the Monte Carlo engine's version, and the episodes
    drawn. The documentation's test compares a committed figure's against the shipped scenario and this
    engine, so that a figure made by other numbers fails it."""
    return provenance(solution.roadmap.scenario.name, str(solution.roadmap._data.scenario_sha256), ENGINE_VERSION,
                      None if options is None else f"{options.episodes} episodes, seed {options.seed}")
