"""Grasp detection on synthetic finger gap / effort signals shaped like a force-limited loop."""

import mujoco
import numpy as np
import pytest
from quadmanip.services.manipulation.gripper import GraspMonitor, GripperConfig, GripState

pytestmark = pytest.mark.unit

CFG = GripperConfig(open_gap=0.12)
DT = 0.002


def _close_on(width: float, force: float, t_end: float = 1.0):
    """First-order finger closing from open_gap to `width`; effort saturates on contact."""
    t = np.arange(0.0, t_end, DT)
    gap = np.maximum(width, CFG.open_gap - 0.2 * t)  # 0.2 m/s closing speed
    effort = np.where(gap > width + 1e-9, 0.3 * force, force if width > 0 else 0.0)
    return t, gap, effort


def test_close_on_object_is_holding_with_measured_width():
    mon = GraspMonitor(CFG)
    mon.command_close(0.0)
    t, gap, eff = _close_on(0.05, CFG.max_force)
    states = [mon.update(ti, g, e) for ti, g, e in zip(t, gap, eff, strict=True)]
    assert states[-1] is GripState.HOLDING
    assert mon.grasp_gap == pytest.approx(0.05, abs=1e-6)
    # no decision while the fingers still move (3 cm at 0.2 m/s = 0.15 s of travel)
    first = states.index(GripState.HOLDING)
    assert t[first] >= (CFG.open_gap - 0.05) / 0.2 + CFG.settle_time - 1e-9


def test_close_on_nothing_is_empty():
    mon = GraspMonitor(CFG)
    mon.command_close(0.0)
    t, gap, eff = _close_on(0.0, CFG.max_force)
    for ti, g, e in zip(t, gap, eff, strict=True):
        mon.update(ti, g, e)
    assert mon.state is GripState.EMPTY


def test_stalled_without_effort_is_not_holding():
    """Fingers stopped at 3 cm with (almost) no effort: not a grasp."""
    mon = GraspMonitor(CFG)
    mon.command_close(0.0)
    for ti in np.arange(0.0, 1.0, DT):
        mon.update(ti, 0.03, 0.5 * CFG.hold_min_effort)
    assert mon.state is GripState.EMPTY


def _holding_at(width: float) -> GraspMonitor:
    mon = GraspMonitor(CFG)
    mon.command_close(0.0)
    t, gap, eff = _close_on(width, CFG.max_force)
    for ti, g, e in zip(t, gap, eff, strict=True):
        mon.update(ti, g, e)
    assert mon.holding
    return mon


def test_slip_during_carry_is_lost():
    mon = _holding_at(0.04)
    # object slides out: fingers close further to the stop
    t2 = np.arange(1.0, 1.3, DT)
    g2 = np.maximum(0.0, 0.04 - 0.2 * (t2 - 1.0))
    seen = [mon.update(ti, g, CFG.max_force) for ti, g in zip(t2, g2, strict=True)]
    assert seen[-1] is GripState.LOST
    lost_at = t2[seen.index(GripState.LOST)]
    # lost when the fingers meet ((0.04 - empty_gap) / 0.2 m/s)
    assert lost_at - 1.0 == pytest.approx((0.04 - CFG.empty_gap) / 0.2, abs=2 * DT)


def test_object_turning_in_the_grip_is_still_held():
    """A spoon pinched across its 37 mm width rolls onto its 11 mm thickness: the gap
    shrinks by far more than slip_gap, then stalls with the force on."""
    mon = _holding_at(0.037)
    t2 = np.arange(1.0, 1.6, DT)
    g2 = np.maximum(0.011, 0.037 - 0.3 * (t2 - 1.0))
    seen = [mon.update(ti, g, CFG.max_force) for ti, g in zip(t2, g2, strict=True)]
    assert GripState.LOST not in seen
    assert mon.holding and mon.grasp_gap == pytest.approx(0.011) and mon.shifts == 1


def test_effort_drop_is_lost_only_after_debounce():
    mon = GraspMonitor(CFG)
    mon.command_close(0.0)
    t, gap, eff = _close_on(0.04, CFG.max_force)
    for ti, g, e in zip(t, gap, eff, strict=True):
        mon.update(ti, g, e)
    # a 50 ms effort dip (shorter than the debounce) keeps holding
    for ti in np.arange(1.0, 1.05, DT):
        mon.update(ti, 0.04, 0.0)
    for ti in np.arange(1.05, 1.2, DT):
        mon.update(ti, 0.04, CFG.max_force)
    assert mon.holding
    for ti in np.arange(1.2, 1.2 + CFG.lost_debounce + 4 * DT, DT):
        mon.update(ti, 0.04, 0.0)
    assert mon.state is GripState.LOST


def test_open_resets():
    mon = GraspMonitor(CFG)
    gap, force = mon.command_open(0.0)
    assert gap == CFG.open_gap and force == CFG.max_force
    assert mon.state is GripState.OPEN
    gap, force = mon.command_close(0.1, max_force=10.0)
    assert gap == CFG.close_gap and force == 10.0


def _squeeze_thin_plate(thickness: float, max_force: float) -> tuple[float, float, float]:
    """The description's gripper (sim actuator layer, sim.toml gains) closing on a rigid
    plate fixed between the pads, gravity off: returns (gap, effort, contact normal force
    summed over both pads) after 1.5 s."""
    from quadmanip.common import robot_description as rd
    from quadmanip.common.config import load_config
    from quadmanip.sim.actuators import ActuatorConfig, ActuatorLayer
    from quadmanip.sim.engine import SimConfig

    spec = rd.robot_spec()
    spec.option.gravity = [0.0, 0.0, 0.0]
    m0 = spec.compile()
    d0 = mujoco.MjData(m0)
    mujoco.mj_resetDataKeyframe(m0, d0, m0.key("home").id)
    mujoco.mj_forward(m0, d0)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, d0.site("gripper_tcp").xmat)
    plate = spec.worldbody.add_body(name="plate", pos=d0.site("gripper_tcp").xpos.copy(), quat=quat)
    plate.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.01, thickness / 2, 0.01])
    m = spec.compile()
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    sim_cfg = load_config(SimConfig, "sim").actuators
    act = ActuatorLayer(m, sim_cfg, rd.LEG_JOINTS, rd.ARM_JOINTS, rd.GRIPPER_JOINTS)
    assert isinstance(sim_cfg, ActuatorConfig)
    d.qpos[act.gripper.qpos] = 0.03
    mujoco.mj_forward(m, d)
    assert act.set_gripper_command(0.0, 0.0, max_force)
    pid = m.body("plate").id
    for _ in range(1500):
        act.apply(d)
        mujoco.mj_step(m, d)
    normal = 0.0
    f6 = np.zeros(6)
    for k in range(d.ncon):
        c = d.contact[k]
        if pid in (m.geom_bodyid[c.geom1], m.geom_bodyid[c.geom2]):
            mujoco.mj_contactForce(m, d, k, f6)
            normal += f6[0]
    return act.gripper_gap(d), float(act.tau[act.gripper.act[0]]), normal


@pytest.mark.parametrize("thickness", [0.004, 0.02])
def test_blocked_fingers_squeeze_at_the_force_limit(thickness):
    # A real force-limited parallel gripper closing on an object stalls at the object's
    # width and presses each pad on it with the commanded force (its current limit), even
    # on a bowl's 4 mm rim: the gap loop must saturate, not stop at kp x (a few mm).
    gap, effort, normal = _squeeze_thin_plate(thickness, 30.0)
    assert gap == pytest.approx(thickness, abs=3e-4)  # stalled on the plate (pads ~0.1 mm in)
    assert effort == pytest.approx(-30.0, abs=0.5)  # closing force saturated
    assert normal == pytest.approx(2 * 30.0, rel=0.03)  # both pads press with 30 N each


def test_heavier_objects_are_squeezed_harder_up_to_the_rated_force():
    """30 N for light or unknown objects, 100 N/kg above that, never beyond the gripper's
    rated force from the robot description (40 N)."""
    from quadmanip.common.robot_description import robot_info
    from quadmanip.services.manipulation.config import load_manipulation_config
    from quadmanip.services.manipulation.gripper import grasp_force

    g = load_manipulation_config().gripper
    assert g.rated_force == robot_info().gripper_max_force == 40.0
    assert grasp_force(g, 0.0) == g.max_force == 30.0  # unknown mass
    assert grasp_force(g, 0.026) == 30.0  # the cup
    assert grasp_force(g, 0.35) == 35.0
    assert grasp_force(g, 0.414) == 40.0  # the coffee can: capped at the rated force


# ------------------------------------------------------------------ a restart while holding


def _start(mon: GraspMonitor, gap: float, effort: float, t_end: float = 0.5) -> list[GripState]:
    """Readings of fingers standing still at ``gap`` with ``effort``, no command sent."""
    return [mon.update(t, gap, effort) for t in np.arange(0.0, t_end, DT)]


def test_a_restart_with_an_object_squeezed_infers_holding_once_settled():
    mon = GraspMonitor(CFG)
    states = _start(mon, 0.04, 0.8 * CFG.max_force)
    assert states[-1] is GripState.HOLDING and mon.inferred
    assert mon.grasp_gap == pytest.approx(0.04)
    # only once the readings have stood still for settle_time
    first = states.index(GripState.HOLDING)
    assert first * DT >= CFG.settle_time - 1e-9
    assert all(s is GripState.OPEN for s in states[:first])
    # from then on it is an ordinary hold: the fingers meeting is LOST
    assert mon.update(1.0, CFG.empty_gap, 0.0) is GripState.LOST


@pytest.mark.parametrize(
    ("gap", "effort"),
    [
        (0.0005, 25.0),  # closed on nothing: the fingers met, squeezing each other
        (0.12, 0.0),  # open
        (0.03, 0.5),  # stopped at 3 cm without effort (e.g. a limp gripper)
    ],
)
def test_a_restart_without_an_object_squeezed_infers_nothing(gap, effort):
    mon = GraspMonitor(CFG)
    assert _start(mon, gap, effort)[-1] is GripState.OPEN and not mon.inferred


def test_fingers_still_moving_at_start_are_not_a_grip():
    mon = GraspMonitor(CFG)
    t = np.arange(0.0, 0.5, DT)
    for ti in t:  # opening at 0.1 m/s with effort (the old process's last command)
        mon.update(ti, 0.02 + 0.1 * ti, 10.0)
    assert mon.state is GripState.OPEN


def test_the_first_command_ends_the_inference():
    mon = GraspMonitor(CFG)
    mon.command_open(0.0)
    assert _start(mon, 0.04, 20.0)[-1] is GripState.OPEN
    held = GraspMonitor(CFG)
    _start(held, 0.04, 20.0)
    assert held.inferred
    held.command_open(1.0)
    assert not held.inferred and held.state is GripState.OPEN
    # and it can be switched off
    off = GraspMonitor(GripperConfig(open_gap=0.12, infer_at_start=False))
    assert _start(off, 0.04, 20.0)[-1] is GripState.OPEN
