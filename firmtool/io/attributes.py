"""The attributes of a roadmap's stages, validated like its datasets: type, shape and range.

A stage's attributes say how it was computed (the inputs' hashes, the solver's status, the
densification rounds...). A command reads them as plain values (``int(attrs["iterations"])``,
``SolveStatus[attrs["status"]]``): one missing, NaN, an array or a bogus string would fail deep
inside a command with a message naming nothing. :func:`check_stage_attributes` checks, when a
command first touches a stage, every attribute firmtool reads, and refuses a wrong one in one line
naming the file, the attribute and its group. Attributes firmtool does not know are not read (their
type and size are checked on reading by :mod:`firmtool.io.hdf5`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from firmtool.errors import RoadmapError

# The names of firmtool.graph.dp.SolveStatus (io sits below graph; tests/test_untrusted.py checks they agree)
SOLVE_STATUSES = ("CONVERGED", "MAX_ITERATIONS")
SOLVE_METHODS = ("value", "policy")


@dataclass(frozen=True)
class Attribute:
    """What one attribute must be.

    kind : ``"int"`` (an integer, not a bool), ``"number"`` (finite), ``"text"``, ``"choice"`` (one
        of ``choices``), ``"int_array"`` (1-D integers).
    low : the least value of a number (inclusive), or None.
    positive : a number must be > 0.
    required : a command reads it without a default.
    """

    kind: str
    low: float | None = None
    positive: bool = False
    required: bool = False
    choices: tuple[str, ...] = ()

    def expected(self) -> str:
        if self.kind == "int":
            return "an integer" + ("" if self.low is None else f" >= {self.low:g}")
        if self.kind == "number":
            bound = " > 0" if self.positive else "" if self.low is None else f" >= {self.low:g}"
            return f"a finite number{bound}"
        if self.kind == "choice":
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.kind == "int_array":
            return "a 1-D array of integers"
        return "a text"

    def accepts(self, value: Any) -> bool:
        if self.kind == "text":
            return isinstance(value, str)
        if self.kind == "choice":
            return isinstance(value, str) and value in self.choices
        if self.kind == "int_array":
            a = np.asarray(value)
            return a.ndim == 1 and a.dtype.kind in "iu"
        if isinstance(value, (bool, np.bool_)):
            return False
        if self.kind == "int":
            ok = isinstance(value, (int, np.integer))
        else:
            ok = isinstance(value, (int, float, np.integer, np.floating)) and math.isfinite(float(value))
        if not ok:
            return False
        if self.positive and not float(value) > 0:
            return False
        return self.low is None or float(value) >= self.low


# The hashes are compared for equality only (a stage whose hash is not the current one is recomputed or
# refused as stale): any text will do, an array or a number will not.
_ENCODING = {"encoding-type": Attribute("text"), "encoding-version": Attribute("int", low=0),
             "inputs_sha256": Attribute("text"), "scenario_sha256": Attribute("text")}
_COUNT = Attribute("int", low=0)
_CODE = Attribute("int")

# Every attribute firmtool reads from each stage group (the writers: firmtool.pipeline).
STAGE_ATTRIBUTES: dict[str, dict[str, Attribute]] = {
    "nodes": {**_ENCODING, "densify_rounds": _COUNT, "connect_added": _COUNT, "connect_budget": _COUNT,
              "connect_stop_reason": Attribute("text"), "validity_checker": Attribute("text"),
              "robot_files_sha256": Attribute("text"), "start": _COUNT, "goals": Attribute("int_array")},
    "controllers": {**_ENCODING, "node_radius": Attribute("number", positive=True),
                    "covariance_tolerance": Attribute("number", low=0.0)},
    "edges": {**_ENCODING, "inputs_sha256": Attribute("text", required=True), "seed": _COUNT,
              "engine_version": _COUNT, "failed_edges": _COUNT, "failure_code": _CODE, "timeout_code": _CODE,
              "goal_miss_code": _CODE, "particles_added": _COUNT, "particles_first_pass": _COUNT},
    "policy": {**_ENCODING, "status": Attribute("choice", required=True, choices=SOLVE_STATUSES),
               "iterations": Attribute("int", low=0, required=True),
               "residual": Attribute("number", low=0.0, required=True),
               "failure_cost": Attribute("number", positive=True, required=True),
               "method": Attribute("choice", required=True, choices=SOLVE_METHODS),
               "interval_method": Attribute("text"), "interval_prior": Attribute("number", low=0.0),
               "interval_samples": Attribute("int", low=1), "deadline_steps": Attribute("int", low=1),
               "deadline_success_probability": Attribute("number", low=0.0)},
}
# Root attributes read as text besides those the reader checks itself (schema_version, seed, the scenario).
# The scenario file's path, stat and sha256 (firmtool.io.scenario_source): compared by stat, then by a
# bounded read of a same-size file.
ROOT_ATTRIBUTES = {"created": Attribute("text"), "firmtool_version": Attribute("text"),
                   "scenario_file": Attribute("text"), "scenario_file_size": _COUNT,
                   "scenario_file_mtime_ns": _COUNT, "scenario_file_sha256": Attribute("text"),
                   "estimation_stream": Attribute("int", low=1)}  # firmtool.io.roadmap_format.STREAM_ATTR


def check_attributes(path: str | Path, group: str, attrs: Mapping[str, Any],
                     schema: Mapping[str, Attribute]) -> None:
    """Refuse the first attribute of ``attrs`` (of the group ``group``, e.g. ``"/policy"``) that
    ``schema`` does not accept, or a required one that is missing.

    Raises
    ------
    RoadmapError
        ``FILE: attribute 'KEY' of '/GROUP' is missing`` or ``... is not EXPECTED`` (one line).
    """
    for key, rule in schema.items():
        if key not in attrs:
            if rule.required:
                raise RoadmapError(f"{path}: attribute '{key}' of '{group}' is missing (file damaged or from "
                                   "another tool)")
            continue
        if not rule.accepts(attrs[key]):
            raise RoadmapError(f"{path}: attribute '{key}' of '{group}' is not {rule.expected()} (found "
                               f"{_shown(attrs[key])}; file damaged or from another tool)")


def check_stage_attributes(path: str | Path, stage: str, attrs: Mapping[str, Any]) -> None:
    """:func:`check_attributes` with the schema of ``stage`` (a stage firmtool does not know: nothing)."""
    check_attributes(path, f"/{stage}", attrs, STAGE_ATTRIBUTES.get(stage, {}))


def _shown(value: Any) -> str:
    """A short description of a bad value: a number itself, else its type and shape (never the
    content of a text: the file is someone else's)."""
    if isinstance(value, str):
        return f"a text of {len(value)} characters"
    a = np.asarray(value)
    if a.ndim:
        return f"an array of shape {a.shape}"
    if a.dtype.kind in "biuf":
        return repr(a.item())
    return type(value).__name__
