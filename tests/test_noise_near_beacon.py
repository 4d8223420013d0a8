"""The ``near_beacon`` noise law (firmtool.models.noise.NearBeacon) against its closed form."""

from __future__ import annotations

import numpy as np
import pytest

from firmtool.errors import InputError
from firmtool.models import noise


def test_near_beacon_is_the_step_in_the_distance():
    law = noise.make("near_beacon", std=2.0, radius=1.5, near_factor=0.5)
    s = np.array([[0.0, 0.0], [1.5, 1.5], [1.5000001, 3.0], [10.0, 0.7]])
    expected = np.array([[2.0, 2.0], [2.0, 2.0], [4.0, 4.0], [4.0, 2.0]])  # 0.5 * 4 within 1.5, 4 beyond
    np.testing.assert_array_equal(law.variance(s), expected)
    assert law.variance(s).shape == s.shape


def test_near_beacon_is_registered_for_scenarios_and_has_no_compiled_twin():
    assert "near_beacon" in noise.names(scenario_only=True)
    cls = noise.get("near_beacon")
    assert cls.compiled is None  # the numpy engine runs it
    assert [f.name for f in cls.fields] == ["std", "radius", "near_factor"]
    law = cls.from_values({"std": 1.0, "radius": 2.0, "near_factor": 0.25})
    np.testing.assert_allclose(law.variance(np.array([[1.0], [3.0]])), [[0.25], [1.0]])


def test_an_unknown_form_names_near_beacon():
    with pytest.raises(InputError, match="near_beacon"):
        noise.get("no_such_form")
