"""ft.forward_kinematics (issue 54, 6): the documented way to check that a goal ball is reachable,
against independent truths: yourdfpy's forward kinematics of the URDF arm, the planar arm's closed
form, the point robot's identity."""

from __future__ import annotations

import numpy as np
import pytest

import firmtool as ft
from firmtool.errors import InputError


def test_the_urdf_arms_tip_is_yourdfpys():
    yourdfpy = pytest.importorskip("yourdfpy")
    from conftest import ROOT

    urdf = yourdfpy.URDF.load(str(ROOT / "scenarios" / "robots" / "arm7.urdf"))
    rng = np.random.default_rng(0)
    q = rng.uniform(-1.0, 1.0, size=(5, 7))
    tips = ft.forward_kinematics("arm7_shelf", q)
    for qi, tip in zip(q, tips):
        urdf.update_cfg(qi)
        np.testing.assert_allclose(tip, urdf.get_transform("tip", "base_link")[:3, 3], atol=1e-12)
    assert ft.forward_kinematics("arm7_shelf", q[0]).shape == (3,)


def test_the_planar_arms_tip_is_the_closed_form_and_the_point_is_itself():
    q = np.array([0.3, -0.2, 0.1, 0.4, -0.5, 0.2, 0.0, 0.1])
    angles = np.cumsum(q)
    tip = 0.25 * np.array([np.cos(angles).sum(), np.sin(angles).sum()])  # 8 links of 0.25, base at 0
    np.testing.assert_allclose(ft.forward_kinematics("arm8_lightdark", q), tip, atol=1e-12)
    state = np.concatenate([q, np.ones(8)])  # a whole state: the velocities do not move the tip
    np.testing.assert_allclose(ft.forward_kinematics("arm8_lightdark", state), tip, atol=1e-12)
    np.testing.assert_allclose(ft.forward_kinematics("smoke", [[1.0, 2.0], [3.0, 0.5]]), [[1.0, 2.0], [3.0, 0.5]])


def test_bad_configurations_are_named():
    with pytest.raises(InputError, match=r"q: expected \(M, 8\) configurations or \(M, 16\) states, found shape \(3,\)"):
        ft.forward_kinematics("arm8_lightdark", [0.0, 1.0, 2.0])
    with pytest.raises(InputError, match="q: expected finite"):
        ft.forward_kinematics("smoke", [np.nan, 1.0])
