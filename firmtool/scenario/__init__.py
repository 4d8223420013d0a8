"""Scenarios: a problem stated in a TOML file (or in Python), validated into frozen, typed dataclasses.

Every key is declared once (:mod:`firmtool.util.schema`): the sections' keys in
:mod:`firmtool.scenario.fields`, a robot's ``[model]`` keys by the robot
(:attr:`firmtool.robots.Robot.model_fields`), a noise form's ``[measurement]`` keys by the form
(:mod:`firmtool.models.noise`), an obstacle kind's keys by the kind (:mod:`firmtool.geometry.shapes`).

- :mod:`firmtool.scenario.specs`: the sections as dataclasses (``ModelSpec``, ``WorldSpec``, ...);
- :mod:`firmtool.scenario.fields`: the declared keys of each section;
- :mod:`firmtool.scenario.read`: TOML text to validated sections, every mistake reported at once;
- :mod:`firmtool.scenario.core`: :class:`Scenario`, reading files and shipped names, scenarios made
  and changed in Python, written back to TOML;
- :mod:`firmtool.scenario.docs`: the scenario reference and ``firmtool init``'s templates.
"""

from firmtool.scenario.core import (
                                    Scenario,
                                    load_scenario,
                                    parse_scenario,
                                    resolve_scenario,
                                    scenario_description,
                                    shipped_scenarios,
)
from firmtool.scenario.fields import MEASUREMENT_FIELDS, OPTIONAL_SECTIONS, sections
from firmtool.scenario.specs import (
                                    MEASUREMENT_KINDS,
                                    START_MODES,
                                    STREAMS,
                                    ControllerSpec,
                                    CostSpec,
                                    EstimationSpec,
                                    ExecutionSpec,
                                    MeasurementSpec,
                                    ModelSpec,
                                    RoadmapSpec,
                                    TaskSpec,
                                    WorldSpec,
                                    stream_of,
                                    with_recorded_stream,
)

__all__ = ["MEASUREMENT_FIELDS", "MEASUREMENT_KINDS", "OPTIONAL_SECTIONS", "START_MODES", "STREAMS", "ControllerSpec", "CostSpec",
           "EstimationSpec", "ExecutionSpec", "MeasurementSpec", "ModelSpec", "RoadmapSpec", "Scenario", "TaskSpec",
           "WorldSpec", "load_scenario", "parse_scenario", "resolve_scenario", "scenario_description", "sections",
           "shipped_scenarios", "stream_of", "with_recorded_stream"]
