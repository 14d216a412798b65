"""The robot description against the paper (Tables 1, 2, eq. 1, Section 6.2.2) and physics.

Paper constants are written here on purpose: the model is checked against the paper, not
against itself.
"""

from __future__ import annotations

import subprocess
import sys

import mujoco
import numpy as np
import pytest
from quadmanip.common import robot_description as rd

pytestmark = pytest.mark.unit

# Table 1 and Table 2 of the paper.
BODY_LENGTH, BODY_WIDTH, THIGH, CALF = 0.419, 0.2505, 0.22, 0.22
D1, D2, D3, D4, D5 = 0.06, 0.25, 0.06, 0.21, 0.1
MM = 1e-3


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return rd.load_mujoco_model()


@pytest.fixture(scope="module")
def floor_model() -> mujoco.MjModel:
    return rd.robot_only_with_floor()


@pytest.fixture(scope="module")
def pin_model():
    return rd.load_pinocchio_model()


def _random_qpos(model: mujoco.MjModel, rng: np.random.Generator) -> np.ndarray:
    """Random base pose and random joint angles inside every joint's range."""
    qpos = rd.home_qpos(model)
    qpos[0:3] = rng.uniform(-2.0, 2.0, 3)
    quat = rng.normal(size=4)
    qpos[3:7] = quat / np.linalg.norm(quat)
    for j in range(model.njnt):
        if model.jnt_type[j] in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            lo, hi = model.jnt_range[j]
            qpos[model.jnt_qposadr[j]] = rng.uniform(lo, hi)
    return qpos


def _forward(model: mujoco.MjModel, qpos: np.ndarray) -> mujoco.MjData:
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    return data


def _set_gap(model: mujoco.MjModel, qpos: np.ndarray, gap: float) -> None:
    for j in rd.GRIPPER_JOINTS:
        qpos[model.jnt_qposadr[model.joint(j).id]] = gap / 2.0


# --- compile / names --------------------------------------------------------------------
def test_compiles_without_warnings(tmp_path) -> None:
    """MuJoCo and pinocchio load the XML silently; a few physics steps raise no warning."""
    code = (
        "import mujoco, numpy as np\n"
        "from quadmanip.common import robot_description as rd\n"
        "m = rd.robot_only_with_floor(); d = mujoco.MjData(m)\n"
        "mujoco.mj_resetDataKeyframe(m, d, m.key('home').id)\n"
        "mujoco.mj_step(m, d, 200)\n"
        "assert all(w.number == 0 for w in d.warning), [w.number for w in d.warning]\n"
        "rd.load_pinocchio_model()\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout == "" and out.stderr == "", out.stdout + out.stderr
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_names_follow_conventions(model) -> None:
    assert rd.LEG_JOINTS[:3] == ("FL_abad", "FL_hip", "FL_knee")
    assert rd.LEG_JOINTS[-3:] == ("RR_abad", "RR_hip", "RR_knee")
    assert len(rd.JOINTS) == 16 and len(rd.ACTUATORS) == 17
    free = model.joint(rd.FREE_JOINT)
    assert free.type[0] == mujoco.mjtJoint.mjJNT_FREE
    assert model.body(free.bodyid[0]).name == rd.BASE_BODY
    for leg in rd.LEG_NAMES:
        assert tuple(model.joint(f"{leg}_abad").axis) == (1.0, 0.0, 0.0)
        assert tuple(model.joint(f"{leg}_hip").axis) == (0.0, 1.0, 0.0)
        assert tuple(model.joint(f"{leg}_knee").axis) == (0.0, 1.0, 0.0)
    for site in (*rd.FOOT_SITES, rd.IMU_SITE, rd.LIDAR_SITE, rd.GRIPPER_TCP_SITE):
        model.site(site)
    for cam in rd.CAMERAS:
        model.camera(cam)
        model.site(rd.CAMERA_OPTICAL_SITES[cam])
    model.body(rd.ARM_BASE_BODY)
    for j in rd.GRIPPER_JOINTS:
        assert model.joint(j).type[0] == mujoco.mjtJoint.mjJNT_SLIDE


def test_joint_layout_is_the_description_s(model) -> None:
    """common/joint_layout.py (names, counts, slices) matches the MJCF: its hinge joints and
    its actuators, in order; the robot description re-exports the same objects."""
    from quadmanip.common import joint_layout as jl
    from quadmanip.common import messages as msg

    hinges = tuple(
        model.joint(j).name
        for j in range(model.njnt)
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
    )
    assert hinges == jl.JOINTS  # depth-first order of the MJCF = the wire order
    assert tuple(model.actuator(a).name for a in range(model.nu)) == jl.ACTUATORS
    assert (jl.N_LEG_JOINTS, jl.N_ARM_JOINTS, jl.N_JOINTS) == (12, 4, 16)
    assert jl.JOINTS[jl.LEG_SLICE] == jl.LEG_JOINTS and jl.JOINTS[jl.ARM_SLICE] == jl.ARM_JOINTS
    assert [jl.LEG_JOINTS[jl.leg_slice(i)][0] for i in range(jl.N_LEGS)] == [
        f"{leg}_abad" for leg in jl.LEG_NAMES
    ]
    for name in ("JOINTS", "LEG_JOINTS", "ARM_JOINTS", "ACTUATORS", "LEG_SLICE", "ARM_SLICE"):
        assert getattr(rd, name) is getattr(jl, name)
    assert msg.example(msg.JointState).q.shape == (jl.N_JOINTS,)
    assert msg.example(msg.LegCommand).q_des.shape == (jl.N_LEG_JOINTS,)
    assert msg.example(msg.ArmTrajectory).kp.shape == (jl.N_ARM_JOINTS,)


# --- Table 1 ----------------------------------------------------------------------------
def test_trunk_and_legs_match_table1(model) -> None:
    geo = rd.leg_geometry(model)
    assert geo.trunk_length == pytest.approx(BODY_LENGTH, abs=MM)
    assert geo.trunk_width == pytest.approx(BODY_WIDTH, abs=MM)
    # abduction axes inside the trunk's corners, thighs outside its sides
    assert np.all(np.abs(geo.hip_positions[:, 0]) < BODY_LENGTH / 2)
    assert np.all(np.abs(geo.hip_positions[:, 1]) < BODY_WIDTH / 2)
    assert np.all(np.abs(geo.hip_positions[:, 1] + geo.abad_offsets) > BODY_WIDTH / 2)
    # lengths measured by forward kinematics in random configurations
    rng = np.random.default_rng(3)
    for _ in range(10):
        data = _forward(model, _random_qpos(model, rng))
        for leg in rd.LEG_NAMES:
            hip = data.xanchor[model.joint(f"{leg}_hip").id]
            knee = data.xanchor[model.joint(f"{leg}_knee").id]
            foot = data.site(f"{leg}_foot").xpos
            assert np.linalg.norm(knee - hip) == pytest.approx(THIGH, abs=MM)
            assert np.linalg.norm(foot - knee) == pytest.approx(CALF, abs=MM)


# --- Table 2 and eq. (1) ------------------------------------------------------------------
def test_arm_offsets_match_table2(model) -> None:
    dims = rd.arm_dimensions(model)
    for key, value in dict(d1=D1, d2=D2, d3=D3, d4=D4, d5=D5).items():
        assert dims[key] == pytest.approx(value, abs=MM), key
    rng = np.random.default_rng(4)
    for _ in range(10):
        data = _forward(model, _random_qpos(model, rng))
        base = data.body(rd.ARM_BASE_BODY).xpos
        a1, a2, a3, a4 = (data.xanchor[model.joint(j).id] for j in rd.ARM_JOINTS)
        tcp = data.site(rd.GRIPPER_TCP_SITE).xpos
        assert np.linalg.norm(a1 - base) == pytest.approx(D1, abs=MM)
        assert np.linalg.norm(a2 - a1) == pytest.approx(D2, abs=MM)
        assert np.linalg.norm(a3 - a2) == pytest.approx(np.hypot(D3, D4), abs=MM)
        assert np.linalg.norm(a4 - a3) < MM
        assert np.linalg.norm(tcp - a4) == pytest.approx(D5, abs=MM)


def _tr(x: float, y: float, z: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def _ry(a: float) -> np.ndarray:
    t = np.eye(4)
    c, s = np.cos(a), np.sin(a)
    t[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    return t


def _rx(a: float) -> np.ndarray:
    t = np.eye(4)
    c, s = np.cos(a), np.sin(a)
    t[:3, :3] = [[1, 0, 0], [0, c, -s], [0, s, c]]
    return t


def eq1(th: np.ndarray) -> np.ndarray:
    """Eq. (1) of the paper, written out with Table 2's constants."""
    return (
        _tr(0, 0, D1)
        @ _ry(th[0])
        @ _tr(0, 0, D2)
        @ _ry(th[1])
        @ _tr(D4, 0, D3)
        @ _ry(th[2])
        @ _rx(th[3])
        @ _tr(D5, 0, 0)
    )


def test_eq1_matches_gripper_tcp(model) -> None:
    rng = np.random.default_rng(5)
    arm_q = rd.joint_qpos_indices(model, rd.ARM_JOINTS)
    for _ in range(50):
        qpos = _random_qpos(model, rng)
        data = _forward(model, qpos)
        world_base = np.eye(4)
        world_base[:3, :3] = data.body(rd.ARM_BASE_BODY).xmat.reshape(3, 3)
        world_base[:3, 3] = data.body(rd.ARM_BASE_BODY).xpos
        world_tcp = np.eye(4)
        world_tcp[:3, :3] = data.site(rd.GRIPPER_TCP_SITE).xmat.reshape(3, 3)
        world_tcp[:3, 3] = data.site(rd.GRIPPER_TCP_SITE).xpos
        base_tcp = np.linalg.inv(world_base) @ world_tcp
        np.testing.assert_allclose(base_tcp, eq1(qpos[arm_q]), atol=1e-9)
    # theta = 0: upper arm vertical, so the wrist is d1 + d2 + d3 above arm_base
    zero = rd.home_qpos(model)
    zero[arm_q] = 0.0
    data = _forward(model, zero)
    wrist = data.xanchor[model.joint("arm_j4").id] - data.body(rd.ARM_BASE_BODY).xpos
    rot = data.body(rd.ARM_BASE_BODY).xmat.reshape(3, 3)
    np.testing.assert_allclose(rot.T @ wrist, [D4, 0.0, D1 + D2 + D3], atol=1e-9)


# --- masses and limits ------------------------------------------------------------------
def test_masses(model) -> None:
    info = rd.robot_info(model)
    assert info.leg_mass < 0.10 * info.total_mass  # Section 6.2.2
    assert 12.0 <= info.trunk_mass <= 15.0
    assert 1.5 <= info.arm_mass <= 2.5  # light arm, Section 6.1
    assert info.total_mass == pytest.approx(float(model.body_mass.sum()))
    assert info.total_mass == pytest.approx(info.trunk_mass + info.leg_mass + info.arm_mass)


def test_actuators_are_limited_motors(model) -> None:
    info = rd.robot_info(model)
    act = rd.actuator_indices(model)
    assert model.nu == 17
    for a in act:
        assert model.actuator_dyntype[a] == mujoco.mjtDyn.mjDYN_NONE
        assert model.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED
        assert model.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_NONE
        assert model.actuator_gainprm[a, 0] == 1.0 and model.actuator_gear[a, 0] == 1.0
        assert model.actuator_ctrllimited[a]
        lo, hi = model.actuator_ctrlrange[a]
        assert lo == -hi and hi > 0
    for i, name in enumerate(rd.JOINTS):  # each joint motor drives its own joint
        assert model.actuator_trnid[act[i], 0] == model.joint(name).id
    tau = dict(zip(rd.ACTUATORS, info.torque_limits, strict=True))
    vel = dict(zip(rd.ACTUATORS, info.velocity_limits, strict=True))
    for leg in rd.LEG_NAMES:  # Go1 / A1 / Mini-Cheetah class
        assert 20.0 <= tau[f"{leg}_abad"] <= 35.0
        assert 25.0 <= tau[f"{leg}_hip"] <= 35.0
        assert 35.0 <= tau[f"{leg}_knee"] <= 45.0
        for k in rd.LEG_JOINT_KINDS:
            assert 20.0 <= vel[f"{leg}_{k}"] <= 30.0
    assert np.all(info.torque_limits[12:16] <= 25.0)
    assert info.gripper_max_force == pytest.approx(40.0, abs=5.0)
    assert np.all(info.armature > 0) and np.all(info.damping > 0)
    for name, (lo, hi) in info.joint_ranges.items():
        assert lo < hi, name
        assert model.jnt_limited[model.joint(name).id], name


def test_standing_torques_within_limits(model) -> None:
    """Gravity torques at `home` use a fraction of the limits (quasi-static check)."""
    data = _forward(model, rd.home_qpos(model))
    info = rd.robot_info(model)
    jac = np.zeros((3, model.nv))
    tau = np.zeros(model.nv)
    for foot in rd.FOOT_SITES:  # each foot carries a quarter of the weight
        mujoco.mj_jacSite(model, data, jac, None, model.site(foot).id)
        tau += jac.T @ np.array([0.0, 0.0, info.total_mass * 9.81 / 4])
    legs = rd.joint_dof_indices(model, rd.LEG_JOINTS)
    assert np.all(np.abs(tau[legs]) < 0.5 * info.torque_limits[:12])


# --- pinocchio ----------------------------------------------------------------------------
def test_pinocchio_matches_mujoco(model, pin_model) -> None:
    import pinocchio as pin

    pmodel, pdata = pin_model
    assert pmodel.nq == model.nq and pmodel.nv == model.nv
    assert sum(i.mass for i in pmodel.inertias) == pytest.approx(model.body_mass.sum())
    sites = (*rd.FOOT_SITES, rd.GRIPPER_TCP_SITE, rd.IMU_SITE, rd.LIDAR_SITE)
    sites += tuple(rd.CAMERA_OPTICAL_SITES.values())
    rng = np.random.default_rng(6)
    for _ in range(50):
        qpos = _random_qpos(model, rng)
        data = _forward(model, qpos)
        q = rd.mujoco_qpos_to_pinocchio(qpos)
        np.testing.assert_allclose(rd.pinocchio_q_to_mujoco(q), qpos, atol=1e-15)
        pin.framesForwardKinematics(pmodel, pdata, q)
        for s in sites:
            frame = pdata.oMf[pmodel.getFrameId(s)]
            np.testing.assert_allclose(frame.translation, data.site(s).xpos, atol=1e-6)
            np.testing.assert_allclose(frame.rotation, data.site(s).xmat.reshape(3, 3), atol=1e-6)
        for cam in rd.CAMERAS:  # the optical sites sit exactly on the MuJoCo cameras
            frame = pdata.oMf[pmodel.getFrameId(rd.CAMERA_OPTICAL_SITES[cam])]
            rot = data.cam(cam).xmat.reshape(3, 3) @ rd.MUJOCO_CAMERA_TO_OPTICAL
            np.testing.assert_allclose(frame.translation, data.cam(cam).xpos, atol=1e-6)
            np.testing.assert_allclose(frame.rotation, rot, atol=1e-6)
        np.testing.assert_allclose(
            pin.centerOfMass(pmodel, pdata, q), data.subtree_com[model.body("base").id], atol=1e-9
        )


def test_pinocchio_dynamics_and_velocities_match(model, pin_model) -> None:
    """Mass matrix (incl. armature) and site velocities agree once qvel is mapped."""
    import pinocchio as pin

    pmodel, pdata = pin_model
    rng = np.random.default_rng(7)
    for _ in range(5):
        qpos = _random_qpos(model, rng)
        data = mujoco.MjData(model)
        data.qpos[:] = qpos
        data.qvel[:] = rng.normal(size=model.nv)
        mujoco.mj_forward(model, data)
        q = rd.mujoco_qpos_to_pinocchio(qpos)
        v = rd.mujoco_qvel_to_pinocchio(qpos, data.qvel)
        full = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, full)
        mp = pin.crba(pmodel, pdata, q)
        mp = np.triu(mp) + np.triu(mp, 1).T
        jmap = np.eye(model.nv)  # v_pin = jmap @ qvel_mujoco
        jmap[:3, :3] = data.xmat[model.body("base").id].reshape(3, 3).T
        np.testing.assert_allclose(jmap.T @ mp @ jmap, full, atol=1e-9)
        pin.forwardKinematics(pmodel, pdata, q, v)
        pin.updateFramePlacements(pmodel, pdata)
        vel = np.zeros(6)
        for s in (*rd.FOOT_SITES, rd.GRIPPER_TCP_SITE):
            mujoco.mj_objectVelocity(
                model, data, mujoco.mjtObj.mjOBJ_SITE, model.site(s).id, vel, 0
            )
            fv = pin.getFrameVelocity(pmodel, pdata, pmodel.getFrameId(s), pin.LOCAL_WORLD_ALIGNED)
            np.testing.assert_allclose(fv.linear, vel[3:], atol=1e-9)
            np.testing.assert_allclose(fv.angular, vel[:3], atol=1e-9)


# --- keyframes and contacts ---------------------------------------------------------------
def _robot_contacts(model: mujoco.MjModel, data: mujoco.MjData) -> list[tuple[str, str, float]]:
    out = []
    for c in data.contact[: data.ncon]:
        b1 = model.body(model.geom_bodyid[c.geom1]).name
        b2 = model.body(model.geom_bodyid[c.geom2]).name
        out.append((b1, b2, float(c.dist)))
    return out


def test_home_keyframe_stands_on_the_ground(floor_model) -> None:
    data = _forward(floor_model, rd.home_qpos(floor_model))
    radius = rd.leg_geometry(floor_model).foot_radius
    for foot in rd.FOOT_SITES:
        assert abs(data.site(foot).xpos[2] - radius) < 2 * MM  # sphere bottom at z = 0
    assert data.qpos[2] == pytest.approx(0.30, abs=0.01)
    # nothing but the feet touches anything: no self-contact, no penetration
    assert all(a == "world" and dist > -2 * MM for a, _, dist in _robot_contacts(floor_model, data))
    # arm stowed: folded back over the trunk, the gripper inside the trunk's footprint
    top = data.qpos[2] + rd.leg_geometry(floor_model).trunk_height / 2
    tcp = data.site(rd.GRIPPER_TCP_SITE).xpos
    assert tcp[2] > top and abs(tcp[0]) < BODY_LENGTH / 2 and abs(tcp[1]) < BODY_WIDTH / 2
    for body in rd.ARM_BODIES:
        assert data.body(body).xpos[2] > top


def test_lying_keyframe_rests_on_folded_legs(floor_model) -> None:
    data = _forward(floor_model, rd.lying_qpos(floor_model))
    radius = rd.leg_geometry(floor_model).foot_radius
    for foot in rd.FOOT_SITES:
        assert abs(data.site(foot).xpos[2] - radius) < 2 * MM
    for leg in rd.LEG_NAMES:  # calves folded flat: knees as low as the feet
        knee = data.xanchor[floor_model.joint(f"{leg}_knee").id]
        assert abs(knee[2] - data.site(f"{leg}_foot").xpos[2]) < 2 * MM
    assert all(a == "world" and dist > -2 * MM for a, _, dist in _robot_contacts(floor_model, data))
    belly = data.qpos[2] - rd.leg_geometry(floor_model).trunk_height / 2
    assert 0.0 < belly < 0.08
    info = rd.robot_info(floor_model)
    for name, q in zip(rd.JOINTS, rd.lying_joint_positions(floor_model), strict=True):
        lo, hi = info.joint_ranges[name]
        assert lo <= q <= hi


def test_geom_groups(model) -> None:
    for g in range(model.ngeom):
        collides = model.geom_contype[g] or model.geom_conaffinity[g]
        group = rd.ROBOT_COLLISION_GROUP if collides else rd.ROBOT_VISUAL_GROUP
        assert model.geom_group[g] == group, model.geom(g).name


# --- gripper ------------------------------------------------------------------------------
def test_gripper_opening_and_pads(model) -> None:
    info = rd.robot_info(model)
    assert info.gripper_max_gap >= 0.09  # baseball 7.3 cm, Rubik's cube 5.7 cm
    for gap in (0.0, info.gripper_max_gap):
        qpos = rd.home_qpos(model)
        _set_gap(model, qpos, gap)
        data = _forward(model, qpos)
        # inner faces of the pads, measured along the finger axis (wrist y)
        y_axis = data.site(rd.GRIPPER_TCP_SITE).xmat.reshape(3, 3)[:, 1]
        tcp = data.site(rd.GRIPPER_TCP_SITE).xpos
        left, right = (model.geom(p).id for p in rd.FINGER_PAD_GEOMS)
        half = model.geom_size[left, 1]
        inner_left = (data.geom_xpos[left] - tcp) @ y_axis - half
        inner_right = (data.geom_xpos[right] - tcp) @ y_axis + half
        assert inner_left - inner_right == pytest.approx(gap, abs=1e-9)
        assert inner_left == pytest.approx(-inner_right, abs=1e-9)  # tcp centred
        # tendon length is the gap: the gripper actuator's coordinate
        assert data.ten_length[model.tendon(rd.GRIPPER_TENDON).id] == pytest.approx(gap)
    for pad in rd.FINGER_PAD_GEOMS:
        g = model.geom(pad)
        # dry silicone on painted wood / metal; torsional = (2/3) mu a for a patch of a few
        # mm (catalogue objects get per-material pairs, configs/objects.toml)
        assert g.condim[0] in (4, 6) and 0.5 <= g.friction[0] <= 1.0
        assert 0.002 <= g.friction[1] <= 0.006
        assert g.priority[0] > 0


def _settle_arm(model, arm_q, seconds, gripper_force) -> mujoco.MjData:
    """PD on all 16 joints holding `home` legs and `arm_q`, gripper at a constant force."""
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key(rd.HOME_KEY).id)
    qi = rd.joint_qpos_indices(model)
    data.qpos[qi[12:]] = arm_q
    _set_gap(model, data.qpos, 0.1)
    _run_pd(model, data, data.qpos[qi].copy(), seconds, gripper_force)
    return data


KP = np.array([80.0] * 12 + [60.0, 40.0, 15.0, 5.0])
KD = np.array([2.0] * 12 + [2.0, 1.0, 0.3, 0.1])


def _run_pd(model, data, target_fn, seconds, gripper_force) -> None:
    qi, vi, act = (
        rd.joint_qpos_indices(model),
        rd.joint_dof_indices(model),
        rd.actuator_indices(model),
    )
    limit = model.actuator_ctrlrange[act[:16], 1]
    t_end = data.time + seconds
    while data.time < t_end:
        target = target_fn(data.time) if callable(target_fn) else target_fn
        tau = KP * (target - data.qpos[qi]) - KD * data.qvel[vi]
        data.ctrl[act[:16]] = np.clip(tau, -limit, limit)
        data.ctrl[act[16]] = gripper_force
        mujoco.mj_step(model, data)


def _in_tcp_frame(data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """The object's position and orientation in the gripper_tcp frame."""
    tcp = data.site(rd.GRIPPER_TCP_SITE)
    rot = tcp.xmat.reshape(3, 3)
    obj = data.body("obj")
    return rot.T @ (obj.xpos - tcp.xpos), rot.T @ obj.xmat.reshape(3, 3)


@pytest.mark.parametrize(
    ("shape", "size", "mass"),
    [
        ("sphere", (0.0365, 0.0, 0.0), 0.145),  # YCB baseball
        ("box", (0.0445, 0.0225, 0.0875), 0.514),  # YCB sugar box, held across 4.5 cm
    ],
)
def test_gripper_holds_by_friction(shape, size, mass) -> None:
    """A PD-held arm grasps from above and lifts; the object follows without slipping."""
    arm_q = np.array([0.9, 0.6, np.pi / 2 - 1.5, 0.0])  # gripper pointing down
    base = rd.robot_only_with_floor()
    settled = _settle_arm(base, arm_q, 1.5, 20.0)
    tcp = settled.site(rd.GRIPPER_TCP_SITE).xpos.copy()
    spec = rd.robot_spec()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
    body = spec.worldbody.add_body(name="obj", pos=tcp.tolist())
    body.add_freejoint(name="obj")
    body.add_geom(
        type=getattr(mujoco.mjtGeom, f"mjGEOM_{shape.upper()}"),
        size=list(size),
        mass=mass,
        friction=[0.6, 0.005, 0.0001],
    )
    top = tcp[2] - size[2 if shape == "box" else 0]  # a pedestal under the object
    spec.worldbody.add_geom(
        type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.06, 0.06, top / 2], pos=[tcp[0], tcp[1], top / 2]
    )
    model = spec.compile()
    data = mujoco.MjData(model)
    data.qpos[: settled.qpos.size] = settled.qpos
    mujoco.mj_forward(model, data)
    qi = rd.joint_qpos_indices(model)
    hold = data.qpos[qi].copy()
    hold[12:16] = arm_q
    _run_pd(model, data, hold, 1.0, -40.0)  # close with the full grip force
    grip, grip_rot = _in_tcp_frame(data)
    z0 = data.body("obj").xpos[2]

    def lift(t: float, t0: float = data.time) -> np.ndarray:
        s = min(1.0, (t - t0) / 1.0)
        target = hold.copy()
        target[12] -= 0.5 * s  # shoulder back, wrist compensates: a vertical lift
        target[14] += 0.5 * s
        return target

    _run_pd(model, data, lift, 3.0, -40.0)
    assert data.body("obj").xpos[2] - z0 > 0.05  # well clear of the pedestal
    pos, rot = _in_tcp_frame(data)
    assert np.linalg.norm(pos - grip) < 3 * MM  # slip in the gripper's frame
    turn = np.arccos(np.clip((np.trace(grip_rot.T @ rot) - 1.0) / 2.0, -1.0, 1.0))
    assert np.degrees(turn) < 3.0
    assert all(w.number == 0 for w in data.warning)


# --- standing -----------------------------------------------------------------------------
@pytest.mark.parametrize("key", [rd.HOME_KEY, rd.LYING_KEY])
def test_pd_holds_home_pose_for_5s(floor_model, key) -> None:
    """Joint PD toward `home` (ramped over 2 s from `lying`) keeps the robot up for 5 s."""
    data = mujoco.MjData(floor_model)
    mujoco.mj_resetDataKeyframe(floor_model, data, floor_model.key(key).id)
    start = data.qpos[rd.joint_qpos_indices(floor_model)].copy()
    goal = rd.home_joint_positions(floor_model)

    def target(t: float) -> np.ndarray:
        return start + min(1.0, t / 2.0) * (goal - start)

    _run_pd(floor_model, data, target, 2.0, 0.0)
    heights = []
    for _ in range(50):
        _run_pd(floor_model, data, goal, 0.1, 0.0)
        heights.append(data.qpos[2])
        up = data.xmat[floor_model.body("base").id].reshape(3, 3)[:, 2]
        assert up[2] > np.cos(np.radians(5.0))  # roll and pitch below 5 degrees
    assert 0.26 < min(heights) and max(heights) < 0.31
    assert np.ptp(heights[-20:]) < 2 * MM  # at rest, not oscillating
    assert np.linalg.norm(data.qvel[:2]) < 0.05
    assert all(w.number == 0 for w in data.warning)


# --- sensors ------------------------------------------------------------------------------
def test_sensors(model) -> None:
    kinds = {
        "imu_quat": mujoco.mjtSensor.mjSENS_FRAMEQUAT,
        "imu_gyro": mujoco.mjtSensor.mjSENS_GYRO,
        "imu_acc": mujoco.mjtSensor.mjSENS_ACCELEROMETER,
    }
    assert set(rd.IMU_SENSORS.values()) == set(kinds)
    for name, kind in kinds.items():
        s = model.sensor(name)
        assert s.type[0] == kind and s.objid[0] == model.site(rd.IMU_SITE).id
    for j in rd.JOINTS + rd.GRIPPER_JOINTS:
        assert model.sensor(f"{j}_pos").type[0] == mujoco.mjtSensor.mjSENS_JOINTPOS
        assert model.sensor(f"{j}_vel").type[0] == mujoco.mjtSensor.mjSENS_JOINTVEL
    # at rest the accelerometer reads +g upward (specific force)
    floor = rd.robot_only_with_floor()
    data = mujoco.MjData(floor)
    mujoco.mj_resetDataKeyframe(floor, data, floor.key(rd.HOME_KEY).id)
    _run_pd(floor, data, rd.home_joint_positions(floor), 1.5, 0.0)
    acc = data.sensor("imu_acc").data
    assert acc[2] == pytest.approx(9.81, abs=0.2) and np.linalg.norm(acc[:2]) < 0.3


def test_cameras(model) -> None:
    data = _forward(model, rd.home_qpos(model))
    base = data.body("base").xmat.reshape(3, 3)
    front = base.T @ data.site(rd.CAMERA_OPTICAL_SITES[rd.FRONT_CAMERA]).xmat.reshape(3, 3)
    forward = front[:, 2]  # optical z in the base frame
    assert forward[0] > 0.95 and -0.35 < forward[2] < 0  # forward, slightly down
    assert front[1, 0] < -0.99  # image x points to the robot's right
    assert 60 <= model.camera(rd.FRONT_CAMERA).fovy[0] <= 70
    pos = data.site(rd.CAMERA_OPTICAL_SITES[rd.FRONT_CAMERA]).xpos - data.qpos[:3]
    assert base.T @ pos @ [1, 0, 0] >= BODY_LENGTH / 2  # on the trunk front
    grip = data.site(rd.CAMERA_OPTICAL_SITES[rd.GRIPPER_CAMERA]).xmat.reshape(3, 3)
    approach = data.site(rd.GRIPPER_TCP_SITE).xmat.reshape(3, 3)[:, 0]
    assert grip[:, 2] @ approach > np.cos(np.radians(25))  # looks along the approach
    tcp = data.site(rd.GRIPPER_TCP_SITE)
    rel = tcp.xmat.reshape(3, 3).T @ (
        data.site(rd.CAMERA_OPTICAL_SITES[rd.GRIPPER_CAMERA]).xpos - tcp.xpos
    )
    assert abs(rel[1]) < 1e-9 and rel[0] < 0  # centred between the fingers, behind the tips


def test_lidar_sees_360_degrees(floor_model) -> None:
    """Horizontal rays from the LiDAR: the stowed arm and the body block < 15 % of them."""
    data = _forward(floor_model, rd.home_qpos(floor_model))
    site = data.site(rd.LIDAR_SITE)
    top = data.qpos[2] + rd.leg_geometry(floor_model).trunk_height / 2
    assert site.xpos[2] > top
    n = 720
    angles = np.linspace(-np.pi, np.pi, n, endpoint=False)
    rot = site.xmat.reshape(3, 3)
    dirs = (rot @ np.stack([np.cos(angles), np.sin(angles), np.zeros(n)])).T.copy()
    geomid = np.zeros(n, dtype=np.int32)
    dist = np.zeros(n)
    groups = np.array([0, 0, 1, 1, 0, 0], dtype=np.uint8)  # robot geoms only
    lidar_body = floor_model.site(rd.LIDAR_SITE).bodyid[0]
    # the LiDAR's own housing sits on the trunk, so exclude the trunk body; this is
    # exactly what a scan that ignores the robot's own body does too
    mujoco.mj_multiRay(
        floor_model,
        data,
        site.xpos,
        dirs.reshape(-1),
        groups,
        1,
        lidar_body,
        geomid,
        dist,
        None,
        n,
        2.0,
    )
    blocked = np.mean((geomid >= 0) & (dist < 2.0))
    assert blocked < 0.15


@pytest.mark.filterwarnings("ignore:Attach")  # options and the empty prefix, as the sim does
def test_robot_qpos_from_a_bigger_model() -> None:
    """The robot's coordinates are found by name in a world whose qpos starts elsewhere."""
    world = mujoco.MjSpec()
    box = world.worldbody.add_body(name="box", pos=[1.0, 0.0, 0.1])
    box.add_freejoint(name="box")
    box.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 0.05, 0.05], mass=0.2)
    world.worldbody.add_frame().attach_body(rd.robot_spec().body(rd.BASE_BODY), "", "")
    big = world.compile()
    assert big.jnt_qposadr[big.joint(rd.FREE_JOINT).id] == 7  # after the box
    robot = rd.load_mujoco_model()
    qpos = _random_qpos(robot, np.random.default_rng(8))
    full = big.qpos0.copy()
    for j in range(robot.njnt):
        ref, dst = robot.joint(j), big.joint(robot.joint(j).name)
        n = 7 if ref.type[0] == mujoco.mjtJoint.mjJNT_FREE else 1
        full[dst.qposadr[0] : dst.qposadr[0] + n] = qpos[ref.qposadr[0] : ref.qposadr[0] + n]
    np.testing.assert_array_equal(rd.robot_qpos(big, full), qpos)


def test_tcp_in_gripper_camera_is_where_the_sites_put_it(model) -> None:
    """The held-object sphere's centre: the tool centre seen from the gripper camera,
    checked against the compiled world poses at the home keyframe."""
    d = mujoco.MjData(model)
    d.qpos[:] = rd.home_qpos(model)
    mujoco.mj_forward(model, d)
    cam, tcp = d.site(rd.CAMERA_OPTICAL_SITES[rd.GRIPPER_CAMERA]), d.site(rd.GRIPPER_TCP_SITE)
    want = cam.xmat.reshape(3, 3).T @ (tcp.xpos - cam.xpos)
    got = rd.tcp_in_gripper_camera(model)
    np.testing.assert_allclose(got, want, atol=1e-9)
    assert got[2] > 0.03  # ahead of the lens, along the optical axis
