"""Scenarios made in Python and written back as TOML: round trips on every shipped scenario,
validated changes, and a scenario changed with dataclasses.replace never keeping a stale text."""

import dataclasses
import tomllib

import numpy as np
import pytest

from firmtool.errors import ScenarioError
from firmtool.scenario import Scenario, load_scenario, parse_scenario
from firmtool.scenario.core import _settings, is_synced, scenario_to_dict, synced
from conftest import ROOT, open_world

SHIPPED = sorted(p.stem for p in (ROOT / "scenarios").glob("*.toml"))


@pytest.mark.parametrize("name", SHIPPED)
def test_load_to_toml_load_gives_an_equal_scenario(name):
    sc = load_scenario(ROOT / "scenarios" / f"{name}.toml")
    text = sc.to_toml()
    again = parse_scenario(text, "again.toml", grid=sc.world.grid)  # a map travels as cells, not as its file
    assert again == sc and again.to_toml() == text
    assert text != sc.text  # written by tomli-w (the file's comments are gone), not the file itself
    assert Scenario.from_dict(sc.to_dict(), path=sc.path) == sc  # its files (a map) named from its folder
    # every typed setting survived, arrays bit for bit (the comparison is not vacuous)
    for section in ("model", "measurement", "world", "task", "roadmap", "controller", "estimation", "cost"):
        said = _settings(getattr(again, section))  # dataclass fields, and a robot's or noise form's keys
        for name, a in _settings(getattr(sc, section)).items():
            b = said[name]
            assert (np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b), f"{section}.{name}"


def test_equality_is_of_settings_not_of_file_or_comments(tmp_path):
    path = ROOT / "scenarios" / "smoke.toml"
    commented = tmp_path / "other.toml"
    commented.write_text("# a comment\n" + path.read_text())
    assert load_scenario(path) == load_scenario(commented)
    moved = path.read_text().replace("obstacles = [ { center = [2.0, 1.2]", "obstacles = [ { center = [2.0, 1.3]")
    assert moved != path.read_text() and parse_scenario(moved) != load_scenario(path)
    assert load_scenario(path) != "smoke"


def test_from_dict_takes_python_and_numpy_values():
    tables = tomllib.loads(open_world())
    tables["world"]["obstacles"] = [{"center": np.array([3.0, 2.0]), "half_size": (0.4, np.float64(0.3))}]
    tables["task"]["start"] = np.array([1.0, 1.0])
    sc = Scenario.from_dict(tables, "notebook")
    assert sc.world.obstacles[0].center == (3.0, 2.0) and sc.world.obstacles[0].half_size == (0.4, 0.3)
    assert sc.path == "notebook" and is_synced(sc) and parse_scenario(sc.text) == sc


def test_from_dict_is_validated_like_a_file():
    tables = tomllib.loads(open_world())
    tables["model"]["dt"] = -0.1
    with pytest.raises(ScenarioError, match=r"^notebook: model\.dt: expected a number > 0"):
        Scenario.from_dict(tables, "notebook")
    tables["model"]["dt"] = 0.1
    tables["model"]["typo"] = 1
    with pytest.raises(ScenarioError, match=r"model\.typo: unknown field"):
        Scenario.from_dict(tables, "notebook")
    with pytest.raises(ScenarioError, match="cannot be written as TOML"):
        Scenario.from_dict({"scenario": {"name": object()}}, "notebook")


def test_replace_changes_settings_and_validates_them():
    sc = load_scenario(ROOT / "scenarios" / "smoke.toml")
    new = sc.replace(seed=7, estimation={"particles": 50}, cost={"failure_cost": 300.0})
    assert (new.seed, new.estimation.particles, new.cost.failure_cost) == (7, 50, 300.0)
    assert dataclasses.replace(new, seed=sc.seed, estimation=sc.estimation, cost=sc.cost) == sc  # nothing else
    assert is_synced(new) and tomllib.loads(new.text)["scenario"]["description"]  # kept from the file
    assert sc.replace(execution={"max_steps": None}).execution.max_steps == 5000  # None: back to the default
    with pytest.raises(ScenarioError, match=r"smoke\.toml \(modified\): estimation\.particles: expected an integer > 0"):
        sc.replace(estimation={"particles": 0})
    with pytest.raises(TypeError, match="unknown setting 'particles'"):
        sc.replace(particles=5)
    with pytest.raises(TypeError, match="expects a mapping"):
        sc.replace(estimation=5)


@pytest.mark.parametrize("name", ["smoke", "arm8_lightdark"])
def test_dataclasses_replace_gets_the_text_of_its_fields(name):
    sc = load_scenario(ROOT / "scenarios" / f"{name}.toml")
    changed = dataclasses.replace(sc, seed=sc.seed + 1,
                                  estimation=dataclasses.replace(sc.estimation, particles=33),
                                  world=dataclasses.replace(sc.world, hi=(sc.world.hi[0] + 1.0, sc.world.hi[1])))
    assert changed.text == sc.text and not is_synced(changed)  # the stale text dataclasses.replace keeps
    fixed = synced(changed)
    assert fixed == changed and is_synced(fixed) and fixed.path.endswith("(modified)")
    said = parse_scenario(fixed.text)
    assert (said.seed, said.estimation.particles, said.world.hi) == (sc.seed + 1, 33, changed.world.hi)
    assert synced(sc) is sc  # a consistent scenario is left alone


def test_link_lengths_replace_the_links_shorthand():
    sc = load_scenario(ROOT / "scenarios" / "arm8_lightdark.toml")
    assert {"links", "link_length"} <= set(tomllib.loads(sc.text)["model"])  # the file uses the shorthand
    changed = dataclasses.replace(sc, model=dataclasses.replace(sc.model, link_lengths=np.full(8, 0.2)))
    out = scenario_to_dict(changed)["model"]
    assert out["link_lengths"] == [0.2] * 8 and "links" not in out and "link_length" not in out
    assert synced(changed).model.link_lengths.tolist() == [0.2] * 8


def test_the_task_belief_and_goal_ball_round_trip_and_replace():
    """[task]'s start belief, true start and goal ball through the Python API (issue 15)."""
    sc = load_scenario(ROOT / "scenarios" / "smoke.toml")
    wide = sc.replace(task={"start_covariance": np.diag([0.2, 0.1]), "true_start": [0.7, 0.4],
                            "goal_radius": 0.3, "goal_confidence": 0.9})
    t = wide.task
    np.testing.assert_array_equal(t.start_covariance, np.diag([0.2, 0.1]))
    assert t.true_start.tolist() == [0.7, 0.4] and t.goal_radius == 0.3 and t.goal_confidence == 0.9
    assert t.goal_ball and not sc.task.goal_ball
    assert parse_scenario(wide.to_toml()) == wide and Scenario.from_dict(wide.to_dict()) == wide
    # dataclasses.replace of the typed fields gets a text that says them
    back = synced(dataclasses.replace(wide, task=dataclasses.replace(t, goal_confidence=0.99, true_start=None)))
    assert back.task.goal_confidence == 0.99 and back.task.true_start is None and "true_start" not in back.text
    with pytest.raises(ScenarioError, match=r"task.goal_confidence: expected a probability in \(0, 1\)"):
        wide.replace(task={"goal_confidence": 1.5})
    with pytest.raises(ScenarioError, match="task.start_covariance: expected a symmetric matrix"):
        sc.replace(task={"start_covariance": [[0.1, 0.05], [0.0, 0.1]]})
    # the arm's old goal_center is replaced by goal (not kept beside it)
    arm_text = (ROOT / "scenarios" / "arm8_lightdark.toml").read_text().replace("goal = [0.0, 1.2]",
                                                                              "goal_center = [0.0, 1.2]")
    arm = parse_scenario(arm_text, "old_arm.toml")
    moved = arm.replace(task={"goal": [0.05, 1.2]})
    assert moved.task.goal.tolist() == [0.05, 1.2] and "goal_center" not in moved.text
