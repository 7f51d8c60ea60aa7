"""Hand-worked values of the pure reward, cost and safe-set math in ``ursa.envs.tasks``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import butter

from ursa.envs import tasks
from ursa.envs.a1 import butterworth2


def test_upright_reward_maps_up_axis_to_unit_interval() -> None:
    assert tasks.upright_reward(1.0) == 1.0
    assert tasks.upright_reward(0.0) == 0.5
    assert tasks.upright_reward(-1.0) == 0.0
    assert tasks.upright_reward(0.4) == pytest.approx(0.7)  # the gate: tilt of acos(0.4) = 66°


def test_heading_velocity_uses_the_ground_projection_of_the_body_x_axis() -> None:
    # yawed by +90°: body x = world y
    body_x = (0.0, 1.0, 0.0)
    assert tasks.heading_velocity(body_x, (0.0, 2.0, 0.3), 0.0) == (2.0, 0.0, 0.0)
    # world +x is to the right of a robot facing +y: negative lateral velocity
    assert tasks.heading_velocity(body_x, (1.0, 0.0, 0.0), 0.5) == (0.0, -1.0, 0.5)
    # pitched nose-down by 60°: the heading is still +x, planar speed counts in full
    c, s = math.cos(math.pi / 3), math.sin(math.pi / 3)
    pitched = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    v_fwd = tasks.heading_velocity(pitched[:, 0], np.array([0.5, 0.0, -1.0]), 0.0)[0]
    assert v_fwd == pytest.approx(0.5)
    # standing on its tail (body x vertical): heading undefined, planar velocities 0
    assert tasks.heading_velocity((0.0, 0.0, 1.0), (1.0, 1.0, 0.0), 0.2) == (0.0, 0.0, 0.2)


def test_velocity_terms_are_scaled_and_saturate() -> None:
    assert tasks.velocity_terms(0.15, -0.06, 0.5, 0.3, 1.0) == pytest.approx((0.5, 0.2, 0.5))
    assert tasks.velocity_terms(0.9, 0.9, -3.0, 0.3, 1.0) == (1.0, 1.0, 1.0)
    assert tasks.velocity_terms(-0.9, 0.0, 0.0, 0.3, 1.0) == (-1.0, 0.0, 0.0)


def test_regularisers() -> None:
    assert tasks.speed_penalty(np.array([1.0, 2.0, -3.0])) == 14.0
    tau = np.array([[1.0, -2.0], [3.0, 0.0]])
    qd = np.array([[2.0, 1.0], [-1.0, 5.0]])
    # |2| + |-2| + |-3| + |0| = 7 (W), times dt
    assert tasks.work_penalty(tau, qd, 0.01) == pytest.approx(0.07)
    assert tasks.smooth_penalty(np.array([1.0, 0.0]), np.array([0.5, -1.0])) == 1.25


def test_forward_reward_cost_and_safe_by_hand() -> None:
    terms = dict(upr=0.9, velx=0.5, vely=0.2, yaw=0.4, speed=100.0, work=20.0, smooth=3.0)
    # 0.9 + (5·0.5 − 0.5·0.2 − 0.5·0.4) − 0.001·123 = 0.9 + 2.2 − 0.123
    r, c, safe = tasks.forward_reward(terms)
    assert r == pytest.approx(2.977)
    assert c == pytest.approx(0.7 - 2.977)
    assert safe
    # not upright: the velocity terms are gated off
    r, c, safe = tasks.forward_reward({**terms, "upr": 0.6})
    assert r == pytest.approx(0.6 - 0.123)
    assert c == pytest.approx(0.223)
    assert not safe
    # upright but moving backwards: safe with a positive paper cost (documented)
    r, c, safe = tasks.forward_reward({**terms, "velx": -0.5, "speed": 0.0, "work": 0.0})
    assert r == pytest.approx(0.9 - 2.5 - 0.3 - 0.003)
    assert c > 0 and safe


def test_forward_upright_cost_is_the_safe_sets_margin() -> None:
    terms = dict(upr=0.9, velx=-0.5, vely=0.2, yaw=0.4, speed=100.0, work=20.0, smooth=3.0)
    # same reward as the paper's cost; the cost ignores velocity: 0.7 − 0.9
    r, c, safe = tasks.forward_reward(terms, "upright")
    assert r == pytest.approx(tasks.forward_reward(terms)[0])
    assert c == pytest.approx(-0.2) and safe
    assert tasks.forward_reward({**terms, "velx": 1.0}, "upright")[1] == pytest.approx(-0.2)
    r, c, safe = tasks.forward_reward({**terms, "upr": 0.25}, "upright")
    assert c == pytest.approx(0.45) and not safe
    with pytest.raises(ValueError, match="cost must be one of"):
        tasks.forward_reward(terms, "velocity")


def test_posture_deviation_is_relative_to_the_worst_case() -> None:
    stand = np.array([0.0, 0.9, -1.8])
    low = np.array([-0.8, -1.0, -2.68])
    high = np.array([0.8, 2.8, -0.92])
    q = np.array([0.4, 0.9 - 0.95, -1.8 + 2.0])
    # hip 0.4/0.8, upper 0.95/1.9, lower clipped at 1
    np.testing.assert_allclose(tasks.posture_deviation(q, stand, low, high), [0.5, 0.5, 1.0])
    assert tasks.posture_deviation(stand, stand, low, high).tolist() == [0.0, 0.0, 0.0]


def test_posture_terms_are_gated_along_the_chain() -> None:
    dev = np.tile([0.1, 0.2, 0.25], 4)
    assert tasks.posture_terms(0.9, dev) == pytest.approx((0.9, 0.8, 0.75))
    assert tasks.posture_terms(0.7, dev) == (0.0, 0.0, 0.0)  # r_upr must exceed 0.7
    dev_hip = np.tile([0.4, 0.2, 0.25], 4)
    assert tasks.posture_terms(0.9, dev_hip) == pytest.approx((0.6, 0.0, 0.0))
    dev_upper = np.tile([0.1, 0.35, 0.25], 4)
    assert tasks.posture_terms(0.9, dev_upper) == pytest.approx((0.9, 0.65, 0.0))
    # the mean over the four legs decides: one bad hip among good ones
    dev_mix = np.array([0.8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0])
    assert tasks.posture_terms(0.9, dev_mix)[0] == pytest.approx(0.8)


def test_posture_reward_and_paper_cost_by_hand() -> None:
    terms = dict(upr=0.9, hip=0.8, upper=0.75, lower=0.72, speed=10.0, work=5.0, smooth=1.0)
    r, c, safe = tasks.posture_reward(terms)
    assert r == pytest.approx(3.17 - 0.016)
    assert c == pytest.approx(-0.02)  # only the last, un-clipped term remains
    assert safe
    r, c, safe = tasks.posture_reward({**terms, "lower": 0.65})
    assert c == pytest.approx(0.05) and not safe
    r, c, safe = tasks.posture_reward({**terms, "upr": 0.5, "hip": 0.0, "upper": 0.0, "lower": 0.0})
    assert c == pytest.approx(0.2 + 0.7 + 0.7 + 0.7) and not safe


def test_posture_cost_is_negative_exactly_on_the_safe_set() -> None:
    rng = np.random.default_rng(0)
    for _ in range(2000):
        upr = float(rng.uniform(0.5, 1.0))
        dev = rng.uniform(0.0, 0.45, size=12)
        hip, upper, lower = tasks.posture_terms(upr, dev)
        terms = dict(upr=upr, hip=hip, upper=upper, lower=lower, speed=0.0, work=0.0, smooth=0.0)
        _, c, safe = tasks.posture_reward(terms)
        assert (c < 0) == safe


def test_butterworth_matches_scipy() -> None:
    b, a = butterworth2(1.5, 20.0)
    b_ref, a_ref = butter(2, 1.5, fs=20.0)
    np.testing.assert_allclose(b, b_ref, rtol=1e-12)
    np.testing.assert_allclose(a, a_ref, rtol=1e-12)
    assert b.sum() / a.sum() == pytest.approx(1.0)  # unit DC gain
