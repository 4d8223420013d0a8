"""Robots as plugins (firmtool.robots) and the declarative scenario schema (firmtool.util.schema).

- the built-in robots are one module each behind the registry; no robot-name or holonomy branch
  is left outside firmtool/robots/;
- a robot registered from Python, or from an installed package's entry point, is named by a
  scenario and declares its own [model] keys (unknown keys refused, defaults applied);
- a scenario with several mistakes is refused with all of them, on one line;
- every key of every section, robot, noise form and obstacle kind has a type and a doc line.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

from firmtool import robots
from firmtool.errors import InputError, ScenarioError
from firmtool.problem import build_problem
from firmtool.robots import installed
from firmtool.robots.point import PointRobot
from firmtool.scenario import parse_scenario, sections
from firmtool.util.schema import Field, describe

ROOT = Path(__file__).resolve().parents[1]
SMOKE = (ROOT / "scenarios" / "smoke.toml").read_text()


def test_builtin_robots_are_one_module_each():
    for name in ("point", "arm", "unicycle"):
        cls = robots.get(name)
        assert issubclass(cls, robots.Robot) and cls.__module__ == f"firmtool.robots.{name}"
    assert {"point", "arm", "unicycle"} <= set(robots.names())


def test_no_robot_name_or_holonomy_branch_outside_the_robots():
    pattern = re.compile(r'"(arm|point|unicycle)"|nonholonomic')
    hits = [f"{p.relative_to(ROOT)}:{i}" for p in (ROOT / "firmtool").rglob("*.py")
            if "robots" not in p.relative_to(ROOT / "firmtool").parts
            for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert hits == []


def test_unknown_robot_names_the_known_ones():
    with pytest.raises(ScenarioError, match=r"model\.robot: expected one of arm, point, unicycle.*found 'rover'"):
        parse_scenario(SMOKE.replace('robot = "point"', 'robot = "rover"'), "bad.toml")


def test_register_refuses_builtin_names_other_classes_and_non_robots():
    class Mine(PointRobot):
        pass

    with pytest.raises(InputError, match="built in"):
        robots.register("point", Mine)
    with pytest.raises(InputError, match="subclass of firmtool.robots.Robot"):
        robots.register("not_a_robot", dict)
    with pytest.raises(InputError, match="letters, digits"):
        robots.register("bad name", Mine)
    robots.register("test_mine", Mine)
    robots.register("test_mine", Mine)  # the same class again: harmless

    class Other(PointRobot):
        pass

    with pytest.raises(InputError, match="already registered"):
        robots.register("test_mine", Other)
    assert robots.register("test_mine", Other, replace=True) is Other and robots.get("test_mine") is Other


class Hovering(PointRobot):
    """A point robot with a key of its own: a floor it must stay above (its validity)."""

    model_fields = PointRobot.model_fields + (
        Field("floor", "number", 0.25, unit="m", doc="lowest y the robot may reach"),
    )

    def is_valid(self, X):
        return super().is_valid(X) & (np.asarray(X)[:, 1] >= self.scenario.model.floor)


def test_a_registered_robot_reads_its_own_keys():
    robots.register("test_hovering", Hovering, replace=True)
    text = SMOKE.replace('robot = "point"', 'robot = "test_hovering"')
    sc = parse_scenario(text, "h.toml")
    assert sc.model.floor == 0.25 and sc.model.params["floor"] == 0.25  # the declared default
    problem = build_problem(parse_scenario(text.replace("dt = 0.1", "dt = 0.1\nfloor = 0.45"), "h.toml"))
    assert isinstance(problem.robot, Hovering)
    assert not problem.is_valid(np.array([[1.0, 0.4]]))[0] and problem.is_valid(np.array([[1.0, 0.5]]))[0]
    with pytest.raises(ScenarioError, match=r"h\.toml: task\.start: expected a collision-free state"):
        build_problem(parse_scenario(text.replace("dt = 0.1", "dt = 0.1\nfloor = 0.6"), "h.toml"))
    with pytest.raises(ScenarioError, match=r"model\.floor: expected a number, found 'low'"):
        parse_scenario(text.replace("dt = 0.1", 'dt = 0.1\nfloor = "low"'), "h.toml")
    with pytest.raises(ScenarioError, match=r"model\.ceiling: unknown field.*known fields: .*floor"):
        parse_scenario(text.replace("dt = 0.1", "dt = 0.1\nceiling = 2.0"), "h.toml")
    # the built-in point robot does not know the key
    with pytest.raises(ScenarioError, match=r"model\.floor: unknown field"):
        parse_scenario(SMOKE.replace("dt = 0.1", "dt = 0.1\nfloor = 0.45"), "p.toml")


SITE_DIRECTORIES = installed.site_directories


def test_a_robot_from_an_installed_packages_entry_point(tmp_path, monkeypatch):
    """A separately installed package names its robot in the entry-point group firmtool.robots."""
    (tmp_path / "fake_firmtool_robot.py").write_text(
        "from firmtool.robots.point import PointRobot\n\nclass Rover(PointRobot):\n    version = '1'\n")
    dist = tmp_path / "fake_firmtool_robot-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: fake-firmtool-robot\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[firmtool.robots]\ntest_rover = fake_firmtool_robot:Rover\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    # installed: entry points are read from the environment's site-packages folders only (issue 35)
    monkeypatch.setattr(installed, "site_directories", lambda: (tmp_path, *SITE_DIRECTORIES()))
    assert "test_rover" in robots.names()
    problem = build_problem(parse_scenario(SMOKE.replace('robot = "point"', 'robot = "test_rover"'), "r.toml"))
    assert type(problem.robot).__name__ == "Rover" and problem.robot.identity.startswith("fake_firmtool_robot.Rover:1")
    assert robots.registry.is_importable(type(problem.robot))  # workers find it by name
    sys.modules.pop("fake_firmtool_robot", None)


def test_every_mistake_of_a_file_is_reported_on_one_line():
    text = (SMOKE.replace("dt = 0.1", "dt = -0.1").replace("nodes = 10", "nodes = 0")
            .replace("c = 0.0004", "c = 0.0").replace("[cost]", "[cost]\nalpha_tiem = 1.0"))
    with pytest.raises(ScenarioError) as info:
        parse_scenario(text, "many.toml")
    message = str(info.value)
    assert "\n" not in message and message.startswith("many.toml: model.dt: expected a number > 0")
    fields = [f for f, _ in info.value.errors]
    assert fields == ["model.dt", "measurement.c", "roadmap.nodes", "cost.alpha_tiem"]
    for f in fields:
        assert f in message


def test_every_key_is_declared_with_a_type_and_a_doc_line():
    from firmtool.geometry.shapes import KINDS
    from firmtool.models import noise

    groups = dict(sections())
    groups.update({f"model ({name})": robots.get(name).model_fields for name in ("point", "arm", "unicycle")})
    groups.update({f"measurement ({form})": noise.get(form).fields for form in noise.names(scenario_only=True)})
    groups.update({f"obstacle ({kind})": cls.fields for kind, cls in KINDS.items()})
    for group, fields in groups.items():
        rows = describe(fields)
        assert rows, group
        for row in rows:
            assert row["doc"] and row["type"] and "\n" not in row["doc"], (group, row)
    assert any(r["key"] == "link_lengths" for r in describe(robots.get("arm").model_fields))


def test_the_robot_interface_is_the_small_protocols_composed():
    """Robot is the composition of its protocols, each declared once (one class naming what the
    stages call and holding the defaults): every public member of Robot belongs to exactly one
    protocol, no protocol is declared twice (no typing.Protocol beside a defaults class), and the
    built-in robots answer every protocol."""
    import inspect
    import typing

    from firmtool.robots import (base, compiled, drawing, geometry, jumps, model, nominals, relocalisation,
                                 stabilisers, task)
    from firmtool.scenario import load_scenario

    protocols = [model.RobotModel, geometry.RobotGeometry, task.TaskSpace, stabilisers.NodeStabilisers,
                 nominals.Nominals, jumps.JumpAnswers, relocalisation.Relocalising, compiled.CompiledHooks,
                 drawing.Drawable]
    assert [c for c in base.Robot.__mro__[1:-1]] == protocols  # exactly these, composed in this order
    owner: dict[str, type] = {}
    for protocol in protocols:
        assert typing.Protocol not in protocol.__mro__, protocol  # one declaration, not a Protocol and a mixin
        # what it defines (its annotations without a value are what it reads of the robot, e.g. model)
        for k in [k for k in vars(protocol) if not k.startswith("_")]:
            assert k not in owner, f"{k} is in {owner.get(k)} and {protocol}"
            owner[k] = protocol
    public = {k for c in base.Robot.__mro__[:-1] for k in vars(c) if not k.startswith("_")}
    assert public <= set(owner), public - set(owner)
    for module in (model, geometry, task, stabilisers, nominals, jumps, relocalisation, compiled, drawing):
        declared = [c for _, c in inspect.getmembers(module, inspect.isclass) if c.__module__ == module.__name__
                    and (typing.Protocol in c.__mro__ or c.__name__.endswith("Defaults"))]
        assert not declared, declared  # no second declaration of a protocol left in its module
    for name in ("smoke", "arm8_lightdark", "unicycle_lightdark"):
        sc = load_scenario(ROOT / "scenarios" / f"{name}.toml")
        robot = robots.get(sc.model.robot)(sc)
        for protocol in protocols:
            assert isinstance(robot, protocol), (name, protocol)
