"""Convex MPC (single rigid body, PIQP): physics of the solution, constraints, model."""

from __future__ import annotations

import numpy as np
import pytest
from quadmanip.common.rotations import rot_z
from quadmanip.services.locomotion.controller import default_profiles
from quadmanip.services.locomotion.convex_mpc import (
    GRAVITY,
    ConvexMpc,
    MpcParams,
    desired_forces,
)

pytestmark = pytest.mark.unit

MASS = 16.25
INERTIA = np.diag([0.17, 0.33, 0.36])
# Feet of the standing robot relative to its COM (m), FL, FR, RL, RR.
FEET = np.array(
    [[0.19, 0.155, -0.29], [0.19, -0.155, -0.29], [-0.16, 0.155, -0.29], [-0.16, -0.155, -0.29]]
)
TUNED = default_profiles()["tuned"].weights
PAPER = default_profiles()["paper"].weights


def standing_state(z: float = 0.3) -> np.ndarray:
    x = np.zeros(12)
    x[5] = z
    return x


@pytest.mark.parametrize("weights", [TUNED, PAPER], ids=["tuned", "paper"])
@pytest.mark.parametrize("backend", ["dense", "sparse"])
def test_standing_forces_carry_the_weight(weights, backend):
    mpc = ConvexMpc(MpcParams(weights=weights, backend=backend))
    x0 = standing_state()
    sol = mpc.solve(x0, np.tile(x0, (6, 1)), FEET, np.ones((6, 4), bool), MASS, INERTIA)
    assert sol.status == "solved"
    f = sol.first
    assert f[:, 2].sum() == pytest.approx(MASS * GRAVITY, rel=0.01)
    assert np.all(f[:, 2] >= -1e-6)
    mu = mpc.params.mu
    assert np.all(np.abs(f[:, 0]) <= mu * f[:, 2] + 1e-6)
    assert np.all(np.abs(f[:, 1]) <= mu * f[:, 2] + 1e-6)
    # No net moment about the COM: the robot does not start to tip.
    moment = np.cross(FEET, f).sum(axis=0)
    assert np.abs(moment[:2]).max() < 0.5


def test_commanded_acceleration_gives_m_times_a():
    """A reference accelerating at a = 1 m/s² forward needs Σf_x ≈ m·a."""
    mpc = ConvexMpc(MpcParams(weights=TUNED))
    a, dt = 1.0, mpc.params.dt
    x0 = standing_state()
    t = dt * np.arange(1, 7)
    ref = np.tile(x0, (6, 1))
    ref[:, 3] = 0.5 * a * t**2
    ref[:, 9] = a * t
    sol = mpc.solve(x0, ref, FEET, np.ones((6, 4), bool), MASS, INERTIA)
    fx = sol.forces[:, :, 0].sum(axis=1)
    # The force applied now (the first step) is m·a; later steps taper off at the end of
    # the finite horizon, where the last input only shows in the final velocity.
    assert fx[0] == pytest.approx(MASS * a, rel=0.05)
    assert fx[:3].mean() == pytest.approx(MASS * a, rel=0.1)
    assert sol.forces[0, :, 2].sum() == pytest.approx(MASS * GRAVITY, rel=0.02)
    assert sol.predicted[2, 9] == pytest.approx(a * t[2], rel=0.1)


def test_swing_legs_get_no_force_and_stance_pair_carries_all():
    mpc = ConvexMpc(MpcParams(weights=TUNED))
    contact = np.ones((6, 4), bool)
    contact[:3, 0] = contact[:3, 3] = False  # FL+RR swing for the first three steps
    x0 = standing_state()
    sol = mpc.solve(x0, np.tile(x0, (6, 1)), FEET, contact, MASS, INERTIA)
    assert np.all(sol.forces[:3, [0, 3], :] == 0.0)
    assert sol.forces[0, [1, 2], 2].sum() == pytest.approx(MASS * GRAVITY, rel=0.05)
    assert np.all(sol.forces[3:, [0, 3], 2] > 5.0)  # back in stance later


def test_condensed_model_matches_integrated_dynamics():
    """X = A_qp x0 + B_qp U equals a fine Euler integration of the rigid-body model."""
    mpc = ConvexMpc(MpcParams())
    rng = np.random.default_rng(1)
    feet = rng.normal(scale=0.2, size=(6, 4, 3))
    x0 = rng.normal(size=12)
    yaw = 0.4
    aqp, bqp = mpc.condensed(x0, feet, MASS, INERTIA, yaw)
    u = rng.normal(scale=20.0, size=72)
    pred = (aqp @ np.append(x0, -GRAVITY) + bqp @ u).reshape(6, 13)
    rz = rot_z(yaw)
    i_inv = np.linalg.inv(rz @ INERTIA @ rz.T)
    x = np.append(x0, -GRAVITY)
    n_sub = 2000
    h = mpc.params.dt / n_sub
    for k in range(6):
        f = u[12 * k : 12 * k + 12].reshape(4, 3)
        torque = np.cross(feet[k], f).sum(axis=0)
        for _ in range(n_sub):
            dx = np.zeros(13)
            dx[0:3] = rz.T @ x[6:9]
            dx[3:6] = x[9:12]
            dx[6:9] = i_inv @ torque
            dx[9:12] = f.sum(axis=0) / MASS
            dx[11] += x[12]
            x = x + h * dx
        assert np.abs(x - pred[k]).max() < 1e-4


def test_desired_forces_balance_moments():
    contact = np.ones((1, 4), bool)
    u = desired_forces(FEET[None], contact, MASS)[0]
    assert u[:, 2].sum() == pytest.approx(MASS * GRAVITY)
    moment = np.cross(FEET, u).sum(axis=0)
    assert np.abs(moment).max() < 1e-6
    # Rear feet are closer to the COM, so they carry more.
    assert u[2, 2] > u[0, 2]


def test_no_contact_gives_zero_forces():
    mpc = ConvexMpc(MpcParams())
    x0 = standing_state()
    sol = mpc.solve(x0, np.tile(x0, (6, 1)), FEET, np.zeros((6, 4), bool), MASS, INERTIA)
    assert sol.status == "no_contact"
    assert np.all(sol.forces == 0.0)
    # Free fall in the prediction.
    assert sol.predicted[-1, 11] == pytest.approx(-GRAVITY * 0.18, rel=1e-6)


def test_bad_inputs_raise():
    mpc = ConvexMpc(MpcParams())
    with pytest.raises(ValueError):
        mpc.solve(np.zeros(11), np.zeros((6, 12)), FEET, np.ones((6, 4), bool), MASS, INERTIA)
    with pytest.raises(ValueError):
        ConvexMpc(MpcParams(backend="nope"))


def test_config_file_loads_both_profiles_and_rejects_typos():
    from quadmanip.common.config import ConfigError
    from quadmanip.services.locomotion.controller import load_locomotion_config

    cfg = load_locomotion_config()
    assert cfg.profile == "tuned"
    assert cfg.profiles["paper"].weights == PAPER  # Table 3 as printed
    assert cfg.profiles["paper"].gait.t_swing == 0.3 and cfg.profiles["paper"].gait.t_stance == 0.1
    assert cfg.mpc.horizon == 6 and cfg.mpc.dt == pytest.approx(0.03)
    assert load_locomotion_config(profile="paper").profile == "paper"
    with pytest.raises(ConfigError):
        load_locomotion_config(profile="nope")
    with pytest.raises(ConfigError):
        load_locomotion_config(**{"mpc.horizn": 6})
