"""The scenario reference against the loader, and the templates of ``firmtool init``.

- every key the loader accepts is documented, and the reference documents no key the loader
  rejects: the loader is probed with an unknown key in every section and case (robot, noise form,
  obstacle kind, goal kind), and the "known fields" its error lists are compared with the reference;
- every example of the reference is accepted by the loader's own check of its key;
- ``firmtool init`` writes, for each robot, a scenario that ``firmtool check`` accepts and that
  builds and solves; it refuses to replace a file without ``--force``.
"""

from __future__ import annotations

import re
import tomllib

import pytest
import tomli_w
from typer.testing import CliRunner

from firmtool import robots
from firmtool.cli import app
from firmtool.errors import ScenarioError
from firmtool.geometry.shapes import KINDS
from firmtool.scenario import OPTIONAL_SECTIONS, parse_scenario, sections
from firmtool.scenario.docs import (
    builtin_noise_forms,
    builtin_robots,
    reference,
    reference_markdown,
    template,
    template_robots,
    toml_value,
)
from firmtool.util.schema import Errors, read_value

runner = CliRunner()
PROBE = "zz_probe"


def known_fields(data: dict, table: str) -> set[str]:
    """The keys the loader accepts in ``table`` of the scenario ``data``: its error for an unknown key
    there lists them."""
    with pytest.raises(ScenarioError) as info:
        parse_scenario(tomli_w.dumps(data), "probe.toml")
    field = f"{table}.{PROBE}" if table else PROBE
    for f, expected in info.value.errors:
        if f == field:
            m = re.search(r"known fields: (.*)$", expected)
            assert m, expected
            return set(m.group(1).split(", "))
    raise AssertionError(f"no unknown-field error for {field}: {info.value.errors}")


def base(robot: str) -> dict:
    return tomllib.loads(template("probe", robot))


def documented(table: str, when: str | None = "") -> set[str]:
    """Keys the reference lists for ``table`` in case ``when`` ("" the section's own keys, None all cases)."""
    return {k.name for s in reference() for k in s.keys if s.table == table and (when is None or s.when == when)}


def test_sections_are_those_the_loader_knows():
    data = base(robots.registry.DEFAULT_ROBOT)
    data[PROBE] = {"x": 1}
    assert known_fields(data, "") == {s.table for s in reference() if "." not in s.table}
    required = {s.table for s in reference() if not s.when and s.required}
    assert required == set(sections()) - set(OPTIONAL_SECTIONS)


@pytest.mark.parametrize("table", ["scenario", "world", "roadmap", "controller", "estimation", "cost", "execution"])
def test_every_key_of_a_section_is_documented_and_accepted(table):
    data = base(robots.registry.DEFAULT_ROBOT)
    data.setdefault(table, {})[PROBE] = 1
    assert known_fields(data, table) == documented(table)


@pytest.mark.parametrize("robot", builtin_robots())
def test_every_model_key_of_each_robot(robot):
    data = base(robot)
    data["model"][PROBE] = 1
    assert known_fields(data, "model") == documented("model") | documented("model", f'robot = "{robot}"')


@pytest.mark.parametrize("form", builtin_noise_forms())
def test_every_measurement_key_of_each_noise_form(form):
    data = base(robots.registry.DEFAULT_ROBOT)
    data["measurement"] = {"kind": "imperfect", "noise": form, PROBE: 1}
    expected = documented("measurement") | documented("measurement", f'kind = "imperfect", noise = "{form}"')
    assert known_fields(data, "measurement") == expected


def test_perfect_measurements_take_only_the_kind():
    data = base(robots.registry.DEFAULT_ROBOT)
    data["measurement"] = {"kind": "perfect", PROBE: 1}
    assert known_fields(data, "measurement") == {"kind"} <= documented("measurement")


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_key_of_each_obstacle_kind(kind):
    data = base(robots.registry.DEFAULT_ROBOT)
    data["world"]["obstacles"] = [{"kind": kind, PROBE: 1}]
    assert known_fields(data, "world.obstacles[0]") == documented("world.obstacles", f'kind = "{kind}"')


def test_task_keys_are_the_same_for_every_robot():
    """Every robot takes a start belief and a goal state or goal ball (issue 15): one task section."""
    for robot in builtin_robots():
        data = base(robot)
        data["task"][PROBE] = 1
        assert known_fields(data, "task") == documented("task"), robot
    assert {"start_covariance", "true_start", "goal_radius", "goal_confidence"} <= documented("task")


def test_every_example_passes_its_keys_own_check():
    checked = 0
    for s in reference():
        for k in s.keys:
            if not k.example:
                assert not k.required, f"{k.dotted}: a required key needs an example"
                continue
            value = tomllib.loads(k.example)[k.name]
            dims = {}
            if isinstance(value, list):
                dims = {"D": len(value), "start": len(value)}
            errors = Errors("example")
            read_value(errors, s.table, {k.name: value}, k.field, dims)
            assert not errors, (k.dotted, k.example, errors.items)
            checked += 1
    assert checked > 60


def test_the_reference_text_names_every_key_with_its_facts():
    text = reference_markdown()
    for s in reference():
        for k in s.keys:
            assert f"(scenario-key-{s.anchor}-{k.name.lower()})=\n`{k.name}`" in text
            if k.example:
                assert f"Example: `{k.example}`" in text
    assert "`[model]` with `robot = \"arm\"`" in text and "allowed: \\> 0" in text and "unit: s" in text


def test_toml_values_read_back():
    for value in (1, 0.1, 1e10, -2.5, "a \"b\"", [[0.0, 1.0], [2.0, 3.0]], {"center": [1.0, 2.0], "kind": "box"},
                  float("inf"), True):
        assert tomllib.loads(f"x = {toml_value(value)}")["x"] == value


# -- firmtool init ---------------------------------------------------------------------------------------

def test_every_builtin_robot_has_a_template():
    assert set(builtin_robots()) <= set(template_robots())


@pytest.mark.parametrize("robot", ["point", "arm", "unicycle", "urdf"])
def test_init_writes_a_template_that_checks_builds_and_solves(robot, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = runner.invoke(app, ["init", f"my_{robot}", "--robot", robot])
    assert r.exit_code == 0, r.output
    path = tmp_path / f"my_{robot}.toml"
    text = path.read_text()
    assert text.count("\n# ") > 40  # every key commented with its doc
    r = runner.invoke(app, ["check", str(path)])
    assert r.exit_code == 0 and r.stdout.startswith(f"ok: {path}"), r.output
    # as written, with fewer particles to keep the test short
    path.write_text(re.sub(r"(?m)^particles = \d+", "particles = 30", text))
    out = tmp_path / f"my_{robot}.h5"
    r = runner.invoke(app, ["build", str(path), "-o", str(out), "--workers", "1"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["solve", str(out), "--json"])
    assert r.exit_code == 0, r.output


def test_init_refuses_to_replace_a_file_unless_forced(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text("# my own work\n")
    r = runner.invoke(app, ["init", "mine", "-o", str(path)])
    assert r.exit_code == 2 and "exists; refusing to replace it" in r.output
    assert path.read_text() == "# my own work\n"
    r = runner.invoke(app, ["init", "mine", "-o", str(path), "--force"])
    assert r.exit_code == 0 and "[scenario]" in path.read_text()


@pytest.mark.parametrize("args, phrase", [
    (["init", "x", "--robot", "tank"], "--robot: expected one of"),
    (["init", "bad name"], "NAME: expected a non-empty name"),
])
def test_init_bad_input_is_one_line_exit_2(args, phrase, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = runner.invoke(app, args)
    assert r.exit_code == 2 and phrase in r.output and r.output.count("\n") == 1, r.output
    assert not list(tmp_path.iterdir())
