"""The honesty guard trips on every non-physical way of moving the robot or the objects.

Forbidden mechanisms are added to the real ``paper-1`` world the way a dishonest change
would: in the spec before compiling (equalities, mocap bodies, tendons, actuators,
gravity compensation) or by writing ``MjData`` between steps (``xfrc_applied``,
``qfrc_applied``, ``eq_active``, ``mocap_pos``). The sanctioned paths (the test-only
disturbance channel, the gripper's finger coupling, a normal run) must not trip it. The
last test is the island-sleeping experiment behind ``configure_sleep``: an object creeping
off a rim must fall, not be frozen in place.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported

import dataclasses  # noqa: E402
import logging
from collections.abc import Callable

import mujoco
import numpy as np
import pytest
from quadmanip.common import messages as msg
from quadmanip.common import robot_description as rd
from quadmanip.sim.engine import (
    PhysicsConfig,
    SimConfig,
    SimEngine,
    configure_sleep,
    standing_data,
)
from quadmanip.sim.honesty import HonestyGuard
from quadmanip.sim.node import load_world
from quadmanip.sim.world.objects import add_object, load_catalogue
from test_engine import _engine, _hold  # the engine tests' construction path and PD hold

pytestmark = pytest.mark.unit

OBJ = "rubiks_cube"  # an object of paper-1
FINGER = "gripper_left_finger"
EQ = mujoco.mjtEq
OBJT = mujoco.mjtObj


@pytest.fixture(scope="module")
def world():
    return load_world("paper-1")


def _edited(edit: Callable[[mujoco.MjSpec], object]):
    """A fresh paper-1 world recompiled after ``edit(spec)`` (its own spec: edits do not
    leak into other tests)."""
    w = load_world("paper-1")
    edit(w.spec)
    return dataclasses.replace(w, model=w.spec.compile())


def _run(eng, ticks: int) -> None:
    out = eng.observe(sensors=False)
    for _ in range(ticks):
        out = eng.step_tick(_hold(eng, out.tick), sensors=False)


def _guard(model: mujoco.MjModel, **kw) -> HonestyGuard:
    """A guard on a model the engine cannot load (mocap robot or object: no free joint)."""
    robot = np.flatnonzero(model.body_rootid == model.body_rootid[model.body("base").id])
    objects = [b for b in range(model.nbody) if model.body(b).name.startswith("obj/")]
    return HonestyGuard(model, mujoco.MjData(model), robot, objects, **kw)


def _finger_coupling(m: mujoco.MjModel) -> int:
    joints = {m.joint(j).id for j in rd.GRIPPER_JOINTS}
    return next(
        e
        for e in range(m.neq)
        if m.eq_type[e] == EQ.mjEQ_JOINT and {m.eq_obj1id[e], m.eq_obj2id[e]} == joints
    )


# ------------------------------------------------------------------ honest runs
def test_normal_run_with_gripper_is_honest(world, caplog):
    eng = _engine(world)  # island sleeping on, as in configs/sim.toml
    m, d = eng.model, eng.data
    e = _finger_coupling(m)
    assert d.eq_active[e]  # the fingers' coupling is there and active...
    with caplog.at_level(logging.ERROR):
        out = eng.observe(sensors=False)
        for i in range(300):
            if i in (50, 150):  # ...and working: close, then open the fingers
                gap = 0.0 if i == 50 else 0.08
                eng.apply_gripper_command(msg.GripperCommand(stamp=eng.time, gap=gap, max_force=20))
            out = eng.step_tick(_hold(eng, out.tick), sensors=False)
    assert eng.honesty_violations() == []  # ...and not a violation
    assert not eng.honesty.tripped and eng.honesty.first_trip is None
    assert not [r for r in caplog.records if r.name.startswith("quadmanip.sim.honesty")]
    # Objects never sleep (configure_sleep); the flag itself is on.
    assert m.opt.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP
    for name in eng.object_names:
        tree = m.body_treeid[world.object_body_ids[name]]
        assert m.tree_sleep_policy[tree] == mujoco.mjtSleepPolicy.mjSLEEP_NEVER
        assert d.tree_asleep[tree] < 0


def test_finger_coupling_is_excepted_by_its_joints(world):
    m = world.model
    assert _guard(m).violations() == []
    # Without the exception the same equality is reported: it is found by its joints.
    strict = _guard(m, internal_couplings=())
    assert strict.tripped
    assert strict.violations()[0].startswith(f"joint equality {m.eq(_finger_coupling(m)).name!r}")


def test_disturbance_channel_is_not_a_violation(world):
    eng = _engine(world, allow_test_disturbance=True)
    bid = world.object_body_ids[OBJ]
    mass = float(eng.model.body_subtreemass[bid])
    _run(eng, 10)
    for body, force in ((f"obj/{OBJ}", [0, 0, 2 * mass * 9.81]), ("base", [20.0, 0, 0])):
        push = msg.Disturbance(
            stamp=eng.time, force=force, torque=[0, 0, 0.1], duration=0.05, body=body
        )
        assert eng.apply_disturbance(push)
    pushed = 0
    out = eng.observe(sensors=False)
    for _ in range(60):
        eng.apply_leg_command(_hold(eng, out.tick))
        for _ in range(eng.substeps):
            eng.physics_step()
            pushed += bool(np.count_nonzero(eng.data.xfrc_applied))
        out = eng.observe(sensors=False)
    assert pushed == 50  # the 50 ms of the pushes, 1 kHz
    assert eng.honesty_violations() == []


# --------------------------------------------------------- forces from outside
def test_xfrc_written_directly_trips_once_with_count_and_time(world, caplog):
    eng = _engine(world)
    _run(eng, 5)
    t0 = eng.time
    eng.data.xfrc_applied[world.object_body_ids[OBJ], 2] = 1.0
    with caplog.at_level(logging.ERROR):
        _run(eng, 5)  # 10 physics steps with the foreign force in place
    v = eng.honesty_violations()
    assert len(v) == 1 and "external force" in v[0] and f"obj/{OBJ}" in v[0]
    assert "10 step(s)" in v[0] and f"t={t0:.3f} s" in v[0]
    assert eng.honesty.first_trip == pytest.approx(t0)
    logged = [r for r in caplog.records if r.name == "quadmanip.sim.honesty"]
    assert len(logged) == 1 and logged[0].levelno == logging.ERROR  # new ones only


def test_xfrc_added_on_top_of_an_active_push_trips(world):
    eng = _engine(world, allow_test_disturbance=True)
    push = msg.Disturbance(stamp=0.0, force=[10.0, 0, 0], torque=[0, 0, 0], duration=0.2)
    assert eng.apply_disturbance(push)
    _run(eng, 5)
    assert eng.honesty_violations() == []
    eng.data.xfrc_applied[world.object_body_ids[OBJ], 0] += 0.5  # a second, foreign push
    eng.physics_step()
    v = eng.honesty_violations()
    assert len(v) == 1 and "external force" in v[0]
    assert f"obj/{OBJ}" in v[0] and "'base'" not in v[0]  # the channel's push is not named


@pytest.mark.parametrize("who", ["object", "robot"])
def test_qfrc_applied_trips(world, who):
    eng = _engine(world)
    m = eng.model
    body = world.object_body_ids[OBJ] if who == "object" else m.body("arm_link2").id
    eng.data.qfrc_applied[m.body_dofadr[body]] = 0.01
    eng.physics_step()
    v = eng.honesty_violations()
    assert len(v) == 1 and "qfrc_applied" in v[0] and m.body(body).name in v[0]


# ------------------------------------------------------------------ equalities
def _weld_object(spec):
    return spec.add_equality(type=EQ.mjEQ_WELD, objtype=OBJT.mjOBJ_BODY, name1=f"obj/{OBJ}")


def _connect_object_to_finger(spec):
    return spec.add_equality(
        type=EQ.mjEQ_CONNECT, objtype=OBJT.mjOBJ_BODY, name1=f"obj/{OBJ}", name2=FINGER
    )


def _weld_sites(spec):
    spec.body(f"obj/{OBJ}").add_site(name="hook")
    spec.worldbody.add_site(name="nail", pos=[0, 0, 1])
    return spec.add_equality(type=EQ.mjEQ_WELD, objtype=OBJT.mjOBJ_SITE, name1="hook", name2="nail")


def _lock_robot_joint(spec):
    return spec.add_equality(type=EQ.mjEQ_JOINT, name1="FL_knee")


def _couple_drawer_to_arm(spec):
    return spec.add_equality(type=EQ.mjEQ_JOINT, name1="cabinet/drawer_top/slide", name2="arm_j1")


def _fix_gripper_tendon(spec):
    return spec.add_equality(type=EQ.mjEQ_TENDON, name1="gripper_gap")


def _couple_drawers(spec):  # house only: allowed
    return spec.add_equality(
        type=EQ.mjEQ_JOINT, name1="cabinet/drawer_top/slide", name2="cabinet/drawer_left/slide"
    )


@pytest.mark.parametrize("active_at_load", [True, False])
@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (_weld_object, f"weld equality 'cheat' on 'world', 'obj/{OBJ}'"),
        (_connect_object_to_finger, f"connect equality 'cheat' on '{FINGER}', 'obj/{OBJ}'"),
        (_weld_sites, f"weld equality 'cheat' on 'world', 'obj/{OBJ}'"),
        (_lock_robot_joint, "joint equality 'cheat' on 'FL_calf'"),
        (_couple_drawer_to_arm, "joint equality 'cheat' on 'arm_link1', 'cabinet/drawer_top'"),
        (_fix_gripper_tendon, f"tendon equality 'cheat' on '{FINGER}', 'gripper_right_finger'"),
        (_couple_drawers, None),
    ],
    ids=["weld", "connect", "weld-sites", "joint-lock", "joint-couple", "tendon", "house-only"],
)
def test_equality_on_robot_or_object_trips(edit, expected, active_at_load):
    def add(spec):
        eq = edit(spec)
        eq.name, eq.active = "cheat", active_at_load

    w = _edited(add)
    if edit is _fix_gripper_tendon:  # MuJoCo 4.0: "tendon equality does not yet support
        # sleeping" (a FatalError in mj_forward), so this one runs without sleeping
        cfg = SimConfig(physics=PhysicsConfig(sleep=False))
        eng = SimEngine(w, cfg, data=standing_data(w), cameras=False, lidar=False)
    else:
        eng = _engine(w)
    e = eng.model.eq("cheat").id
    if active_at_load:
        assert eng.honesty.tripped == (expected is not None)
    else:
        assert not eng.honesty.tripped
        _run(eng, 3)
        assert not eng.honesty.tripped
        eng.data.eq_active[e] = 1  # switched on at run time
    t_on = eng.time
    _run(eng, 2)
    if expected is None:
        assert eng.honesty_violations() == []
        return
    (v,) = eng.honesty_violations()
    assert v.startswith(expected)
    steps = 4 + (1 if active_at_load else 0)  # + the check at load
    assert f"{steps} step(s) from t={t_on:.3f} s" in v


# ------------------------------------------------------------------------ mocap
def _make_mocap(name):
    def edit(spec):
        body = spec.body(name)
        for j in list(body.joints):
            spec.delete(j)
        body.mocap = True
        for k in list(spec.keys):  # their qpos hold the removed free joint
            spec.delete(k)

    return edit


@pytest.mark.parametrize(("body", "who"), [(f"obj/{OBJ}", "object"), ("base", "robot")])
def test_mocap_robot_or_object_trips(body, who):
    w = _edited(_make_mocap(body))
    g = _guard(w.model)
    assert g.tripped and g.violations() == [f"mocap body {body!r} ({who})"]


def _hand_of_god(collidable: bool, weld: bool):
    def edit(spec):
        hand = spec.worldbody.add_body(name="hand", mocap=True, pos=[5, 5, 1])
        hand.add_geom(size=[0.05, 0, 0], contype=int(collidable), conaffinity=int(collidable))
        if weld:
            spec.add_equality(
                name="grab",
                type=EQ.mjEQ_WELD,
                objtype=OBJT.mjOBJ_BODY,
                name1="hand",
                name2=f"obj/{OBJ}",
                active=False,
            )

    return edit


def test_mocap_welded_to_an_object_trips(world):
    eng = _engine(_edited(_hand_of_god(collidable=False, weld=True)))
    assert not eng.honesty.tripped  # a mocap body alone, its weld off
    _run(eng, 2)
    eng.data.mocap_pos[0] += [0.0, 0.0, 0.01]  # not collidable: moving it alone is harmless
    _run(eng, 2)
    assert not eng.honesty.tripped
    eng.data.eq_active[eng.model.eq("grab").id] = 1
    _run(eng, 1)
    (v,) = eng.honesty_violations()
    assert v.startswith(f"weld equality 'grab' on 'obj/{OBJ}', 'hand'")


def test_collidable_mocap_that_moves_trips(world):
    eng = _engine(_edited(_hand_of_god(collidable=True, weld=False)))
    _run(eng, 5)
    assert not eng.honesty.tripped  # a static obstacle is fine
    eng.data.mocap_pos[0] += [0.001, 0.0, 0.0]  # a kinematic pusher is not
    _run(eng, 1)
    (v,) = eng.honesty_violations()
    assert v.startswith("collidable mocap body 'hand' moved")


# ---------------------------------------------------- other structural cheats
def _gravcomp(spec):
    spec.body(f"obj/{OBJ}").gravcomp = 1.0


def _object_motor(spec):
    spec.add_actuator(name="levitate", target=f"obj/{OBJ}/free", trntype=mujoco.mjtTrn.mjTRN_JOINT)


def _sticky_finger(spec):
    spec.add_actuator(name="glue", target=FINGER, trntype=mujoco.mjtTrn.mjTRN_BODY)


def _leash(spec):
    spec.body(f"obj/{OBJ}").add_site(name="collar")
    spec.worldbody.add_site(name="post", pos=[0, 0, 1])
    t = spec.add_tendon(name="leash", limited=True, range=[0, 0.5])
    t.wrap_site("post")
    t.wrap_site("collar")


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (_gravcomp, f"gravity compensation on 'obj/{OBJ}'"),
        (_object_motor, f"actuator 'levitate' acts on object 'obj/{OBJ}'"),
        (_sticky_finger, f"adhesion actuator 'glue' on '{FINGER}'"),
        (_leash, f"tendon 'leash' ties 'world', 'obj/{OBJ}' together"),
    ],
    ids=["gravcomp", "object-motor", "adhesion", "leash"],
)
def test_structural_cheats_trip_at_load(edit, expected):
    g = _guard(_edited(edit).model)
    assert g.violations() == [expected]


# --------------------------------------------------------------- island sleeping
def _rim_scene(name: str, x: float) -> mujoco.MjModel:
    """A catalogue object resting on a table whose edge is at x = 0, body at ``x``."""
    spec = mujoco.MjSpec()
    robot = rd.robot_spec()
    for opt in ("timestep", "integrator", "cone", "impratio"):  # the sim's physics options
        setattr(spec.option, opt, getattr(robot.option, opt))
    spec.worldbody.add_geom(
        type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.3, 0.3, 0.2], pos=[-0.3, 0, 0.2]
    )
    cat = load_catalogue()
    o = cat.objects[name]
    add_object(spec.worldbody, name, o, (x, 0, 0.4 + o.size[2] / 2 + 1e-4), contact=cat.contact)
    return spec.compile()


def _time_to_fall(name: str, past: float, mode: str, horizon: float = 3.0):
    """Settle the object 4 mm inside the edge, slide it (at rest) until its centre of mass
    is ``past`` m beyond the edge, and run: the time it drops 5 cm, or None."""
    m = _rim_scene(name, -0.004)
    d = mujoco.MjData(m)
    for _ in range(1000):
        mujoco.mj_step(m, d)
    settled = d.qpos.copy()
    if mode == "raw":  # MuJoCo's own policy: the object may sleep
        m.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    else:  # "engine": the engine's sleep configuration, sleeping on
        configure_sleep(m, mode == "engine", never=[m.body(f"obj/{name}").id])
    d = mujoco.MjData(m)
    d.qpos[:] = settled
    mujoco.mj_forward(m, d)
    d.qpos[0] += past - d.subtree_com[1][0]  # initial condition, before the first step
    mujoco.mj_forward(m, d)
    z0 = float(d.xpos[1][2])
    while d.time < horizon:
        mujoco.mj_step(m, d)
        if d.xpos[1][2] < z0 - 0.05:
            return float(d.time), False
    return None, bool(d.tree_asleep[0] >= 0)


@pytest.mark.parametrize(("name", "past"), [("cracker_box", 1e-3), ("brick", 2e-4)])
def test_object_creeping_off_a_rim_is_not_frozen_by_sleeping(name, past):
    t_awake, _ = _time_to_fall(name, past, "off")
    t_engine, _ = _time_to_fall(name, past, "engine")
    t_raw, asleep = _time_to_fall(name, past, "raw")
    # Without sleeping it tips over the edge within a second or so...
    assert t_awake is not None and t_awake < 1.5
    # ...MuJoCo's sleeping left to itself freezes it on the rim for good (why objects never
    # sleep: if this starts failing, a MuJoCo update changed it and the choice can be
    # revisited)...
    assert t_raw is None and asleep
    # ...and with the engine's configuration (sleep on, objects never) it falls just the same.
    assert t_engine == pytest.approx(t_awake, abs=0.01)


def test_a_tripped_guard_makes_the_judges_report_invalid(world):
    """The judge's report of a run in which the guard tripped says the trial is invalid
    and why; an honest run's report is valid."""
    eng = _engine(world)
    _run(eng, 10)
    ok = eng.judge_report()
    assert ok is not None and ok.valid and ok.violations == ()
    eng.data.qfrc_applied[eng.model.body_dofadr[world.object_body_ids[OBJ]]] = 0.5
    _run(eng, 2)
    eng.data.qfrc_applied[:] = 0.0
    _run(eng, 10)
    bad = eng.judge_report()
    assert bad is not None and not bad.valid
    assert len(bad.violations) == 1 and "qfrc_applied" in bad.violations[0]
