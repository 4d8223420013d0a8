"""The ROS node's message checks (firmtool.ros.checks, no ROS needed): a JSON message too long or
nested too deep is one refusal naming the field, never an exception that stops the node."""

import pytest

from firmtool.ros import checks


@pytest.mark.parametrize("text", ["[" * 200_000, '{"obstacles": [' + "[" * 200_000 + "]}", "x" * 2_000_000])
def test_hostile_json_is_a_refusal(text):
    with pytest.raises(checks.MessageError) as info:
        checks.read_json(text, "world_update.data")
    assert info.value.field == "world_update.data" and str(info.value).startswith("world_update.data: expected")


def test_plain_json_is_read():
    assert checks.read_json('{"resume": true}', "reset.data") == {"resume": True}
