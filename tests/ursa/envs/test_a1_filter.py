"""The A1's action filter: scipy.signal's Butterworth low-pass on the joint targets."""

from __future__ import annotations

import math

import numpy as np

from ursa.envs.a1 import A1Config, A1Env, butterworth2


def test_coefficients_at_a_quarter_of_the_sample_rate() -> None:
    # bilinear transform pre-warped at fc = fs/4: k = tan(pi/4) = 1, so with n = 1/(2 + sqrt 2)
    # b = (n, 2n, n) and a = (1, 0, (2 - sqrt 2) n)
    b, a = butterworth2(5.0, 20.0)
    n = 1.0 / (2.0 + math.sqrt(2.0))
    np.testing.assert_allclose(b, [n, 2 * n, n], rtol=1e-12)
    np.testing.assert_allclose(a, [1.0, 0.0, (2.0 - math.sqrt(2.0)) * n], rtol=1e-12, atol=1e-15)
    # unit gain at DC, and the -3 dB point at the cutoff
    assert math.isclose(b.sum() / a.sum(), 1.0, rel_tol=1e-12)
    b, a = butterworth2(1.5, 20.0)
    w = np.exp(-1j * 2 * math.pi * 1.5 / 20.0)
    gain = abs(np.polyval(b[::-1], w) / np.polyval(a[::-1], w))
    assert math.isclose(gain, 1 / math.sqrt(2.0), rel_tol=1e-9)


def test_env_filters_targets_from_the_standing_steady_state() -> None:
    env = A1Env(A1Config(action_filter_hz=1.5, rescue=False, init_yaw=0.3), seed=0)
    try:
        stand = env._stand.copy()
        # the standing action (0) keeps the filtered target at the standing pose exactly
        for _ in range(3):
            np.testing.assert_allclose(env._joint_targets([0.0] * 12), stand, atol=1e-12)
        # a step to the calves' upper end: the direct-form recurrence from rest at `stand`
        b, a = butterworth2(1.5, env.config.control_hz)
        action = [0.0, 0.0, 1.0] * 4
        env_raw = A1Env(A1Config(rescue=False, init_yaw=0.3), seed=0)
        x = np.asarray(env_raw._joint_targets(action))
        env_raw.close()
        x1 = x2 = y1 = y2 = stand
        ys = []
        for _ in range(10):
            y = b[0] * x + b[1] * x1 + b[2] * x2 - a[1] * y1 - a[2] * y2
            np.testing.assert_allclose(env._joint_targets(action), y, atol=1e-12)
            x1, x2, y1, y2 = x, x1, y, y1
            ys.append(y[2])
        # the calf's target creeps towards the step (under 10 % after one step), then
        # overshoots it by the 2nd-order Butterworth's 4.3 %
        assert 0 < (ys[0] - stand[2]) / (x[2] - stand[2]) < 0.1
        assert 1.0 < max((v - stand[2]) / (x[2] - stand[2]) for v in ys) < 1.05
    finally:
        env.close()
