"""The calibration plot: each checked policy edge's predicted (Monte Carlo) against executed frequencies."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from firmtool.errors import InputError


def calibration_panels(axes, calibration, *, title: str = "") -> None:
    """Predicted (Monte Carlo) against executed frequencies of every checked policy edge, each with
    its 95% interval: failure (collision or timeout) on ``axes[0]``, landing in the edge's target on
    ``axes[1]``; flagged edges in red and labelled with their ids.

    Parameters
    ----------
    axes : two matplotlib Axes.
    calibration : a :class:`firmtool.results.Calibration` (``Results.calibration``).
    """
    checks = list(calibration.edges)
    for ax, what, name in zip(axes, ("failure", "target"), ("failure: collision or timeout", "landing in the target")):
        ax.plot([0, 1], [0, 1], "--", color="0.5", lw=1, zorder=1, label="executed = predicted")
        for c in checks:
            x, y = getattr(c, f"{what}_estimated"), getattr(c, f"{what}_executed")
            xlo, xhi = getattr(c, f"{what}_estimated_ci95")
            ylo, yhi = getattr(c, f"{what}_executed_ci95")
            flagged = what in c.flagged
            xerr = np.maximum([[x - xlo], [xhi - x]], 0.0)  # an interval holds its estimate (rounding aside)
            yerr = np.maximum([[y - ylo], [yhi - y]], 0.0)
            ax.errorbar([x], [y], xerr=xerr, yerr=yerr, fmt="o",
                        ms=3 + 3 * min(c.traversals, 200) / 200, color="tab:red" if flagged else "tab:blue",
                        elinewidth=0.8, capsize=2, alpha=0.85, zorder=3)
            if flagged:
                ax.annotate(str(c.edge), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7,
                            color="tab:red")
        ax.set_xlim(-0.02, 1.02)
        ax.set_ylim(-0.02, 1.02)
        ax.set_aspect("equal")
        ax.set_xlabel("predicted probability (edge Monte Carlo, 95% interval)")
        ax.set_ylabel("executed frequency (episodes, 95% interval)")
        ax.set_title(name, fontsize=9)
    axes[0].legend(loc="upper left", fontsize=7, frameon=False)
    if title:
        axes[0].figure.suptitle(title, fontsize=10)


def calibration_figure(results, *, dpi: int = 120, title: str | None = None) -> Figure:
    """The calibration plot of executed episodes (:func:`calibration_panels`) on a bare Figure.

    Parameters
    ----------
    results : :class:`firmtool.Results` with a calibration check (``simulate`` on a roadmap).
    dpi : resolution.
    title : the figure's title (default: how many edges were checked and which were flagged).

    Raises
    ------
    InputError
        The results have no calibration check (no edge counts) or no edge was taken often enough.
    """

    cal = results.calibration
    if cal is None or not cal.edges:
        raise InputError("calibration: no policy edge was taken often enough to be checked "
                         f"(>= {cal.min_traversals if cal else '?'} clean traversals); run more episodes")
    fig = Figure(figsize=(9.0, 4.8), dpi=dpi, layout="constrained")
    axes = fig.subplots(1, 2)
    flagged = ", ".join(map(str, cal.flagged_edges)) or "none"
    calibration_panels(axes, cal, title=title if title is not None else
                       f"{cal.edges_checked} of {cal.edges_taken} policy edges checked (>= {cal.min_traversals} "
                       f"traversals) in {len(results.episodes)} episodes; flagged: {flagged}; marker size: "
                       "traversals")
    return fig
