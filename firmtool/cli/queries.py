"""``firmtool solve ROADMAP --goal ...``: new queries on a built roadmap (:mod:`firmtool.pipeline.query`),
their arguments read and checked here, the answers stored in the roadmap by name."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from firmtool.cli.console import num, prob
from firmtool.errors import InputError, cut, quoted
from firmtool.io.limits import LimitError, read_toml_file

TASK_KEYS = ("start", "goal", "goal_radius", "goal_confidence", "start_covariance", "deadline_steps")


def numbers(text: str, option: str) -> list[float]:
    """Comma-separated finite numbers (``--goal 8.5,5``), or one line naming the option."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise InputError(f"{option}: expected comma-separated numbers, e.g. 8.5,5.0; found {quoted(text)}") from None
    if not values or not np.all(np.isfinite(values)):
        raise InputError(f"{option}: expected finite numbers, found {quoted(text)}")
    return values


# Largest task file read: a [task] table of a few lines (a start covariance of 64 x 64 is ~40 KB).
MAX_TASK_BYTES = 2**16


def task_file(path: Path) -> dict[str, Any]:
    """The ``[task]`` fields of a task file (a ``[task]`` table, or its keys at the top level), read
    through the one bounded door of side files (:func:`firmtool.io.limits.read_toml_file`: a regular
    file of at most :data:`MAX_TASK_BYTES`, nesting bounded before parsing)."""
    try:
        data = read_toml_file(path, MAX_TASK_BYTES)
    except FileNotFoundError:
        raise InputError(f"{path}: --task: no such file") from None
    except LimitError as exc:
        field = exc.field or "--task"
        raise InputError(f"{path}: {field}: {exc.message}") from None
    table = data.get("task", data)
    if not isinstance(table, dict):
        raise InputError(f"{path}: task: expected a table")
    unknown = sorted(set(table) - set(TASK_KEYS))
    if unknown:
        raise InputError(f"{path}: task.{cut(unknown[0])}: a query sets only {', '.join(TASK_KEYS)}")
    return dict(table)


def queries_of(goals: list[str], names: list[str], goal_radius: float | None, goal_confidence: float | None,
               start: str | None, start_covariance: str | None, task: Path | None) -> list:
    """The queries the options ask for: one per ``--goal`` (or one from ``--task`` / ``--start``),
    each named by the ``--name`` at its position (none given: named by their task)."""
    from firmtool.pipeline.query import Query, check_query_name  # lazy: the pipeline's import, 1.6 s (cli.app)
    for name in names:  # before anything is read or computed
        check_query_name(name)
    base: dict[str, Any] = task_file(task) if task is not None else {}
    shared = {"goal_radius": goal_radius, "goal_confidence": goal_confidence,
              "start": numbers(start, "--start") if start else None,
              "start_covariance": numbers(start_covariance, "--start-covariance") if start_covariance else None}
    base.update({k: v for k, v in shared.items() if v is not None})
    per_goal = [numbers(g, "--goal") for g in goals] or [base.get("goal")]
    if names and len(names) != len(per_goal):
        raise InputError(f"--name: expected one per query ({len(per_goal)}), found {len(names)}")
    out = []
    for i, goal in enumerate(per_goal):
        fields = {**base, "goal": goal}
        out.append(Query(**{"deadline" if k == "deadline_steps" else k: fields.get(k) for k in TASK_KEYS},
                         name=names[i] if names else None))
    return out


def query_human(r: dict) -> str:
    """One query's summary line (what it reused and computed), above its solve summary."""
    s = r["seconds"]
    return (f"query {r['name']}: {r['goal_nodes']} goal nodes ({r['retired_nodes']} of the roadmap's retired), "
            f"{r['edges']} edges: {r['reused_edges']} reused, {r['estimated_edges']} estimated "
            f"({r['reestimated_edges']} of them again); {num(s['total'], 2)} s; start success probability "
            f"{prob(r['start_success_probability'])}")
