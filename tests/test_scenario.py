"""Scenario loading: shipped files load; broken files give one-line errors naming file and field."""

from pathlib import Path

import pytest

from firmtool.errors import ScenarioError
from firmtool.scenario import load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parents[1]
SMOKE = (ROOT / "scenarios" / "smoke.toml").read_text()


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "scenarios").glob("*.toml")))
def test_shipped_scenarios_load(name):
    sc = load_scenario(ROOT / "scenarios" / name)
    assert sc.name and len(sc.sha256) == 64
    assert sc.roadmap.nodes > 0 and sc.estimation.particles > 0


def test_smoke_values_are_read():
    sc = parse_scenario(SMOKE, "smoke.toml")
    assert sc.model.dynamics == "single_integrator" and sc.measurement.noise == "lightdark_variance"
    assert sc.world.obstacles[0].half_size == (0.3, 0.7)
    assert not sc.perfect and sc.measurement.a == 0.02


def _broken(old: str, new: str) -> str:
    assert old in SMOKE, old
    return SMOKE.replace(old, new, 1)


@pytest.mark.parametrize("text, field, expected", [
    (_broken('dt = 0.1', ''), "model.dt", "missing required field"),
    (_broken('dt = 0.1', 'dt = "fast"'), "model.dt", "expected a number"),
    (_broken('dt = 0.1', 'dt = -0.1'), "model.dt", "expected a number > 0"),
    (_broken('dt = 0.1', 'dt = nan'), "model.dt", "finite"),
    (_broken('dt = 0.1', 'dt = 0.1\ndtt = 0.2'), "model.dtt", "unknown field"),
    (_broken('nodes = 10', 'nodes = 0'), "roadmap.nodes", "> 0"),
    (_broken('nodes = 10', 'nodes = 2.5'), "roadmap.nodes", "expected an integer"),
    (_broken('start = [0.5, 0.5]', 'start = [0.5, 0.5, 1.0]'), "task.goal", "expected shape (3,)"),
    (_broken('bounds = [[0.0, 0.0], [4.0, 3.0]]', 'bounds = [[0.0, 0.0], [4.0]]'), "world.bounds", "expected"),
    (_broken('dynamics = "single_integrator"', 'dynamics = "triple"'), "model.dynamics", "expected one of"),
    (_broken('half_size = [0.3, 0.7]', 'half_size = [0.3, -0.7]'), "world.obstacles[0].half_size", "positive"),
    (_broken('c = 0.0004', 'c = 0.0'), "measurement.c", "> 0"),
    (SMOKE + "\n[extra]\nx = 1\n", "extra", "unknown field"),
    ("this is = not [toml", "", "not valid TOML"),
])
def test_broken_scenarios_name_file_field_and_expectation(text, field, expected):
    with pytest.raises(ScenarioError) as info:
        parse_scenario(text, "bad.toml")
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith("bad.toml")
    assert field in message and expected in message


def test_missing_file_is_reported(tmp_path):
    with pytest.raises(ScenarioError, match="no such file"):
        load_scenario(tmp_path / "nope.toml")
