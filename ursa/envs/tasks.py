"""Reward, cost and safe-set math of the paper's two A1 tasks (URSA paper §5.2 and §5.3).

Every function here is pure: numbers in, numbers out, no simulator. ``ursa.envs.a1`` reads the
simulator once per control step and feeds these functions; tests check them by hand.

Terms (all floats; definitions are the project's, the paper names them without defining them):

- ``upr``    r_upr = up_z / 2 + 0.5, where up_z is the world-z component of the body's up axis
             (DayDreamer's ``RMATask``): 1 upright, 0.5 on its side, 0 upside down.
- ``velx``   r_velx = clip(v_fwd / target_speed, -1, 1): forward velocity in the heading frame
             (the body x axis projected on the ground plane), in units of the target speed.
- ``vely``   r_vely = min(|v_lat| / target_speed, 1): lateral speed in the heading frame.
- ``yaw``    r_yaw = min(|omega_z| / yaw_rate_scale, 1): yaw rate (world z angular velocity).
- ``speed``  r_speed = sum_j qd_j^2 over the 12 joints at the end of the control step (rad²/s²).
- ``work``   r_work = sum over physics substeps and joints of |tau_j * qd_j| * dt (J).
- ``smooth`` r_smooth = sum_j (a_j - a_prev_j)^2, the squared change of the policy action.
- ``hip``, ``upper``, ``lower``: posture terms, 1 - mean normalised deviation of that joint type
             from the standing pose, each gated on the previous term of the chain upr → hip →
             upper → lower exceeding 0.7 (DayDreamer's ``RMATask``).

Forward (§5.2): r = r_upr + 1[r_upr>0.7]·(5 r_velx − 0.5 r_vely − 0.5 r_yaw)
− 0.001 (r_speed + r_work + r_smooth); c = 0.7 − r; safe iff r_upr > 0.7.

Posture (§5.3): r = r_upr + r_hip + r_upper + r_lower − 0.001 (r_speed + r_work + r_smooth);
c = max(0.7 − r_upr, 0) + max(0.7 − r_hip, 0) + max(0.7 − r_upper, 0) + (0.7 − r_lower);
safe iff all four posture terms exceed 0.7.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from operator import mul, sub

import numpy as np

GATE = 0.7
"""Threshold of the paper's gates, safe sets and costs."""
W_VELX = 5.0
W_VELY = 0.5
W_YAW = 0.5
W_REG = 0.001
"""Weight of the regularisers r_speed + r_work + r_smooth."""

FORWARD_TERMS = ("upr", "velx", "vely", "yaw", "speed", "work", "smooth")
POSTURE_TERMS = ("upr", "hip", "upper", "lower", "speed", "work", "smooth")
TASKS = ("forward", "posture")
FORWARD_COSTS = ("paper", "upright")
"""Costs of the forward task: the paper's 0.7 − r, or the upright margin 0.7 − r_upr."""


def upright_reward(up_z: float) -> float:
    """r_upr = up_z / 2 + 0.5 for the world-z component ``up_z`` of the body up axis."""
    return 0.5 * up_z + 0.5


def heading_velocity(
    body_x: Sequence[float] | np.ndarray, lin_vel: Sequence[float] | np.ndarray, yaw_rate: float
) -> tuple[float, float, float]:
    """Forward, lateral and yaw velocity in the heading frame.

    body_x (3,): the body x axis in the world frame (first column of the body-to-world
    rotation); lin_vel (3,): world-frame base velocity; yaw_rate: world-z angular velocity.
    The heading is body_x projected on the ground plane (normalised); when that axis is
    vertical the heading is undefined and both planar velocities are reported as 0.
    Returns (v_fwd, v_lat, yaw_rate); v_lat is positive to the robot's left.
    """
    hx, hy = float(body_x[0]), float(body_x[1])
    norm = math.hypot(hx, hy)
    vx, vy = float(lin_vel[0]), float(lin_vel[1])
    if norm < 1e-6:
        return 0.0, 0.0, float(yaw_rate)
    hx, hy = hx / norm, hy / norm
    return hx * vx + hy * vy, -hy * vx + hx * vy, float(yaw_rate)


def velocity_terms(
    v_fwd: float, v_lat: float, yaw_rate: float, target_speed: float, yaw_rate_scale: float
) -> tuple[float, float, float]:
    """(r_velx, r_vely, r_yaw) from heading-frame velocities; see the module docstring."""
    r_velx = min(max(v_fwd / target_speed, -1.0), 1.0)
    r_vely = min(abs(v_lat) / target_speed, 1.0)
    r_yaw = min(abs(yaw_rate) / yaw_rate_scale, 1.0)
    return r_velx, r_vely, r_yaw


def speed_penalty(qd: Sequence[float] | np.ndarray) -> float:
    """r_speed = sum of squared joint velocities; qd (J,)."""
    return float(sum(map(mul, qd, qd)))


def work_penalty(tau: np.ndarray, qd: np.ndarray, dt: float) -> float:
    """r_work = sum |tau * qd| * dt over substeps and joints; tau, qd (S, J) or flat (S*J,)."""
    return float(np.abs(np.asarray(tau) * np.asarray(qd)).sum() * dt)


def smooth_penalty(
    action: Sequence[float] | np.ndarray, prev_action: Sequence[float] | np.ndarray
) -> float:
    """r_smooth = sum of squared action changes; action, prev_action (A,)."""
    d = list(map(sub, action, prev_action))
    return float(sum(map(mul, d, d)))


def posture_deviation(
    q: np.ndarray, stand: np.ndarray, low: np.ndarray, high: np.ndarray
) -> np.ndarray:
    """Normalised deviation from the standing pose, in [0, 1]; all (J,).

    |q − stand| divided by the worst case max(high − stand, stand − low), clipped to [0, 1]
    (DayDreamer's ``RMATask`` does the same in normalised action units, which is equivalent).
    """
    worst = np.maximum(high - stand, stand - low)
    return np.clip(np.abs(q - stand) / worst, 0.0, 1.0)


def posture_terms(r_upr: float, dev: np.ndarray) -> tuple[float, float, float]:
    """(r_hip, r_upper, r_lower) from deviations dev (12,) ordered leg-major (hip, upper, lower).

    Each term is 1 − mean deviation of its joint type over the four legs, gated on the previous
    term of the chain upr → hip → upper → lower being above ``GATE``.
    """
    d = dev.reshape(4, 3).mean(axis=0)
    r_hip = (1.0 - float(d[0])) if r_upr > GATE else 0.0
    r_upper = (1.0 - float(d[1])) if r_hip > GATE else 0.0
    r_lower = (1.0 - float(d[2])) if r_upper > GATE else 0.0
    return r_hip, r_upper, r_lower


def forward_reward(terms: dict[str, float], cost: str = "paper") -> tuple[float, float, bool]:
    """(reward, cost, safe) of the forward task (§5.2) from the ``FORWARD_TERMS``.

    ``cost="paper"``: the paper's c = 0.7 − r. Note that ``cost <= 0`` implies safe but a safe
    state can have a positive cost (e.g. upright while moving backwards), and that c is the
    reward shifted, so a fast forward gait earns negative costs that pay for falls in the cost
    return; ``safe`` is returned separately and is the paper's safe set r_upr > 0.7.
    ``cost="upright"``: c = 0.7 − r_upr, the safe set's own margin (c <= 0 exactly when safe,
    except on the boundary r_upr == 0.7), in [−0.3, 0.7] whatever the velocity.
    """
    if cost not in FORWARD_COSTS:
        raise ValueError(f"cost must be one of {FORWARD_COSTS}, got {cost!r}")
    upr = terms["upr"]
    gate = 1.0 if upr > GATE else 0.0
    reward = (
        upr
        + gate * (W_VELX * terms["velx"] - W_VELY * terms["vely"] - W_YAW * terms["yaw"])
        - W_REG * (terms["speed"] + terms["work"] + terms["smooth"])
    )
    c = GATE - reward if cost == "paper" else GATE - upr
    return reward, c, upr > GATE


def posture_reward(terms: dict[str, float]) -> tuple[float, float, bool]:
    """(reward, cost, safe) of the posture task (§5.3) from the ``POSTURE_TERMS``.

    The cost is the paper's max(0.7 − r_upr, 0) + max(0.7 − r_hip, 0) + max(0.7 − r_upper, 0)
    + (0.7 − r_lower). With the gating of ``posture_terms`` it is negative exactly when all
    four terms exceed 0.7 (the safe set) and positive otherwise, except on the boundary
    r_lower == 0.7 where it is 0 and the state is unsafe.
    """
    upr, hip, upper, lower = terms["upr"], terms["hip"], terms["upper"], terms["lower"]
    reward = upr + hip + upper + lower - W_REG * (terms["speed"] + terms["work"] + terms["smooth"])
    cost = max(GATE - upr, 0.0) + max(GATE - hip, 0.0) + max(GATE - upper, 0.0) + (GATE - lower)
    safe = upr > GATE and hip > GATE and upper > GATE and lower > GATE
    return reward, cost, safe
