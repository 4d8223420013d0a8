"""The ROS node's contract, as the tutorial states it (docs/tutorials/ros.md): every topic with its
type, every event kind with its fields, every parameter with its default, and the state machine, in
tables that these tests hold to the code (no ROS needed). tests/test_ros.py checks the running node's
topics and events against the same tables."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from firmtool.ros.contract import (
    NODE_EVENTS,
    POLICY_EVENT_FIELDS,
    POLICY_EVENTS,
    SIM_TOPICS,
    STATE_FIELDS,
    STATES,
    TOPICS,
    parameter_defaults,
)

PAGE = Path(__file__).resolve().parents[1] / "docs" / "tutorials" / "ros.md"


def table(heading: str) -> list[list[str]]:
    """The rows (cells as text) of the first table under ``heading``."""
    text = PAGE.read_text()
    start = text.index(heading)
    rows = []
    for line in text[start:].splitlines()[1:]:
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if not set("".join(cells)) <= set("-: "):
                rows.append(cells)
        elif rows:
            break
    return rows[1:]  # without the header


def ticked(cell: str) -> list[str]:
    return re.findall(r"`([^`]+)`", cell)


def documented_topics() -> dict[str, str]:
    return {ticked(row[0])[0]: ticked(row[1])[0] for row in table("### The contract: topics")}


def documented_events() -> dict[str, list[str]]:
    out = {}
    for row in table("### The contract: events"):
        for kind in ticked(row[0]):
            out[kind] = ticked(row[1])
    return out


def test_every_topic_is_documented_with_its_type():
    documented = documented_topics()
    assert documented == {**TOPICS, **SIM_TOPICS}


def test_every_event_kind_is_documented_with_its_fields():
    documented = documented_events()
    assert set(documented) == set(NODE_EVENTS) | set(POLICY_EVENTS)
    for kind, fields in NODE_EVENTS.items():
        assert documented[kind] == list(fields), kind
    for kind in POLICY_EVENTS:
        assert documented[kind] == list(POLICY_EVENT_FIELDS), kind


def test_the_state_topic_fields_are_documented():
    row = next(r for r in table("### The contract: topics") if ticked(r[0])[0] == "~/state")
    assert ticked(row[3]) == list(STATE_FIELDS)


def test_every_parameter_is_documented_with_its_default():
    rows = {ticked(row[0])[0]: row[1] for row in table("### The contract: parameters")}
    defaults = parameter_defaults(0.1)
    assert set(rows) == set(defaults)
    for name, value in defaults.items():
        if name in ("rate", "timeout", "measurement.max_age"):  # from the period: said in words
            continue
        text = ticked(rows[name])[0]
        if isinstance(value, bool):
            assert text == str(value).lower(), name
        elif isinstance(value, float):
            assert float(text) == value, name
        else:
            assert text.strip('"') == value, name


def test_the_state_table_has_every_state():
    text = PAGE.read_text()
    header = text[text.index("### The contract: states"):].split("| message |")[1].splitlines()[0]
    assert [c.strip() for c in header.strip().strip("|").split("|")] == list(STATES)


@pytest.mark.parametrize("kind", ["no_such_kind"])
def test_an_undocumented_kind_fails_the_check(kind):
    """The check can fail: a kind the table lacks is not among the documented ones."""
    assert kind not in documented_events()
