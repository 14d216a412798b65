"""The hardware adapter's pure parts: the Unitree joint table, the low-level wire format and
CRC (byte for byte against the SDK's own serialiser and CRC), the leg safety layer, the
shared command rules, the simulated arm driver, and the sim's e-stop.

No DDS, no processes: SDK messages are built, serialised and checked in memory.
"""

import struct

import mujoco
import numpy as np
import pytest
from quadmanip.common import messages as msg
from quadmanip.common import robot_description as rd
from quadmanip.common.actuator_commands import (
    LegMode,
    LegWatchdog,
    active_segment,
    check_arm_trajectory,
    check_leg_command,
    queue_segment,
)
from quadmanip.common.joint_layout import LEG_JOINTS, N_ARM_JOINTS, N_LEG_JOINTS
from quadmanip.hardware.arm_driver import SimulatedArmDriver
from quadmanip.hardware.leg_safety import LegSafety, LegSafetyConfig, MotorTargets
from quadmanip.hardware.unitree import joint_map as jm
from quadmanip.hardware.unitree import lowlevel as ll
from quadmanip.hardware.unitree.joint_map import JointMapRow, LegJointMap
from quadmanip.hardware.unitree.wire_format import CDR_HEADER_LE
from quadmanip.sim.engine import PhysicsConfig, SimConfig, SimEngine
from unitree_sdk2py.idl.unitree_go.msg.dds_ import LowCmd_, LowState_
from unitree_sdk2py.utils.crc import CRC

pytestmark = pytest.mark.unit

IDX = {name: i for i, name in enumerate(LEG_JOINTS)}
UNITREE_LEGS = ("FR", "FL", "RR", "RL")
KINDS = ("abad", "hip", "knee")


def f32(x: float) -> float:
    """``x`` as a float32 round trip (what the wire carries)."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


# --------------------------------------------------------------------------- joint map
def _custom_rows() -> tuple[JointMapRow, ...]:
    """A robot that differs: shuffled slots in 0..19, mixed signs, non-zero offsets."""
    rng = np.random.default_rng(7)
    motors = rng.permutation(jm.N_SDK_MOTORS)[:N_LEG_JOINTS]
    signs = rng.choice([-1.0, 1.0], N_LEG_JOINTS)
    signs[0] = -1.0
    offsets = rng.uniform(-1.0, 1.0, N_LEG_JOINTS)
    return tuple(
        JointMapRow(name, int(m), float(s), float(o))
        for name, m, s, o in zip(LEG_JOINTS, motors, signs, offsets, strict=True)
    )


def test_table_names_each_leg_joint_and_slot_once():
    assert len(jm.TABLE) == N_LEG_JOINTS
    assert sorted(r.joint for r in jm.TABLE) == sorted(LEG_JOINTS)
    assert sorted(r.motor for r in jm.TABLE) == list(range(N_LEG_JOINTS))
    assert all(r.sign == 1.0 and r.offset == 0.0 for r in jm.TABLE)


def test_table_is_unitree_order_fr_fl_rr_rl():
    slot = {r.joint: r.motor for r in jm.TABLE}
    for leg_i, leg in enumerate(UNITREE_LEGS):
        for k_i, kind in enumerate(KINDS):
            assert slot[f"{leg}_{kind}"] == 3 * leg_i + k_i
    assert slot["FR_abad"] == 0
    assert slot["FL_hip"] == 4
    assert slot["RR_knee"] == 8
    assert slot["RL_abad"] == 9
    # LEG_MAP holds the slot of each of our joints in our wire order.
    np.testing.assert_array_equal(jm.LEG_MAP.motor, [slot[n] for n in LEG_JOINTS])


@pytest.mark.parametrize("rows", [jm.TABLE, _custom_rows()], ids=["go2", "custom"])
def test_round_trips(rows):
    lm = LegJointMap(rows)
    rng = np.random.default_rng(3)
    by_joint = {r.joint: r for r in rows}
    unused = np.setdiff1d(np.arange(jm.N_SDK_MOTORS), [r.motor for r in rows])
    for _ in range(5):
        q, v, k = rng.uniform(-3, 3, (3, N_LEG_JOINTS))
        k = np.abs(k) * 50
        q_sdk = lm.position_to_sdk(q)
        v_sdk = lm.signed_to_sdk(v)
        k_sdk = lm.gains_to_sdk(k)
        for a in (q_sdk, v_sdk, k_sdk):
            assert a.shape == (jm.N_SDK_MOTORS,)
            assert np.all(a[unused] == 0.0)  # slots we do not drive stay 0
        # Each joint lands in its slot with sign and offset.
        for i, name in enumerate(LEG_JOINTS):
            r = by_joint[name]
            assert q_sdk[r.motor] == pytest.approx(r.sign * q[i] + r.offset, abs=1e-12)
            assert v_sdk[r.motor] == pytest.approx(r.sign * v[i], abs=1e-12)
            assert k_sdk[r.motor] == k[i]
        np.testing.assert_allclose(lm.position_from_sdk(q_sdk), q, rtol=0, atol=1e-12)
        np.testing.assert_allclose(lm.signed_from_sdk(v_sdk), v, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(lm.gains_to_sdk(k)[lm.motor], k)


def test_custom_table_has_signs_and_offsets():
    lm = LegJointMap(_custom_rows())
    assert np.any(lm.sign == -1.0) and np.any(lm.sign == 1.0)
    assert np.any(lm.offset != 0.0)
    assert not np.array_equal(lm.motor, jm.LEG_MAP.motor)


@pytest.mark.parametrize(
    "change",
    ["duplicate_motor", "missing_joint", "duplicate_joint", "sign_2", "motor_20", "extra_row"],
)
def test_invalid_tables_raise(change):
    rows = list(jm.TABLE)
    if change == "duplicate_motor":
        rows[1] = JointMapRow(rows[1].joint, rows[0].motor)
    elif change == "missing_joint":
        rows = rows[:-1]
    elif change == "duplicate_joint":
        rows[1] = JointMapRow(rows[0].joint, rows[1].motor)
    elif change == "sign_2":
        rows[5] = JointMapRow(rows[5].joint, rows[5].motor, sign=2.0)
    elif change == "motor_20":
        rows[5] = JointMapRow(rows[5].joint, jm.N_SDK_MOTORS)
    elif change == "extra_row":
        rows.append(JointMapRow(rows[0].joint, 15))
    with pytest.raises(ValueError):
        LegJointMap(tuple(rows))


# ------------------------------------------------------------------ wire format / CRC
def _rand_lowstate(rng: np.random.Generator) -> LowState_:
    """A LowState_ with every field random (ranges the SDK's CRC packer accepts)."""
    st = ll.new_lowstate()

    def fl(n: int | None = None):
        v = rng.uniform(-100.0, 100.0, n)
        return float(v) if n is None else [float(x) for x in v]

    def ui(hi: int, n: int | None = None):
        v = rng.integers(0, hi + 1, n)
        return int(v) if n is None else [int(x) for x in v]

    st.frame_reserve = ui(255)
    st.sn = ui(2**32 - 1, 2)
    st.version = ui(2**32 - 1, 2)
    st.bandwidth = ui(65535)
    imu = st.imu_state
    imu.quaternion = fl(4)
    imu.gyroscope = fl(3)
    imu.accelerometer = fl(3)
    imu.rpy = fl(3)
    imu.temperature = ui(127)
    for m in st.motor_state:
        m.mode = ui(255)
        m.q, m.dq, m.ddq, m.tau_est, m.q_raw, m.dq_raw, m.ddq_raw = fl(7)
        m.temperature = ui(127)
        m.lost = ui(2**32 - 1)
        m.reserve = ui(2**32 - 1, 2)
    b = st.bms_state
    b.version_high, b.version_low, b.status, b.soc = ui(255, 4)
    b.current = int(rng.integers(-(2**31), 2**31))
    b.cycle = ui(65535)
    b.bq_ntc = ui(127, 2)
    b.mcu_ntc = ui(127, 2)
    b.cell_vol = ui(65535, 15)
    st.foot_force = [int(x) for x in rng.integers(-(2**15), 2**15, 4)]
    st.foot_force_est = [int(x) for x in rng.integers(-(2**15), 2**15, 4)]
    st.tick = ui(2**32 - 1)
    st.wireless_remote = ui(255, 40)
    st.bit_flag = ui(255)
    st.adc_reel = fl()
    st.temperature_ntc1 = ui(127)
    st.temperature_ntc2 = ui(127)
    st.power_v = fl()
    st.power_a = fl()
    st.fan_frequency = ui(1000, 4)
    st.reserve = ui(2**32 - 1)
    st.crc = ui(2**32 - 1)
    return st


def _rand_lowcmd(rng: np.random.Generator) -> LowCmd_:
    cmd = ll.new_lowcmd(np.arange(N_LEG_JOINTS))
    cmd.frame_reserve = int(rng.integers(0, 256))
    cmd.sn = [int(x) for x in rng.integers(0, 2**32, 2)]
    cmd.version = [int(x) for x in rng.integers(0, 2**32, 2)]
    cmd.bandwidth = int(rng.integers(0, 65536))
    for m in cmd.motor_cmd:
        m.mode = int(rng.integers(0, 256))
        m.q, m.dq, m.tau, m.kp, m.kd = (float(x) for x in rng.uniform(-100, 100, 5))
        m.reserve = [int(x) for x in rng.integers(0, 2**32, 3)]
    cmd.bms_cmd.off = int(rng.integers(0, 256))
    cmd.bms_cmd.reserve = [int(x) for x in rng.integers(0, 256, 3)]
    cmd.wireless_remote = [int(x) for x in rng.integers(0, 256, 40)]
    cmd.led = [int(x) for x in rng.integers(0, 256, 12)]
    cmd.fan = [int(x) for x in rng.integers(0, 256, 2)]
    cmd.gpio = int(rng.integers(0, 256))
    cmd.reserve = int(rng.integers(0, 2**32))
    cmd.crc = int(rng.integers(0, 2**32))
    return cmd


SEEDS = range(4)


def _flip_motor_q_byte(data: bytes, q: float) -> bytes:
    """``data`` with the low byte of the (unique) float32 ``q`` flipped."""
    pattern = struct.pack("<f", q)
    assert data.count(pattern) == 1
    i = data.index(pattern)
    return data[:i] + bytes([data[i] ^ 0x01]) + data[i + 1 :]


@pytest.mark.parametrize("seed", SEEDS)
def test_lowstate_crc_serialise_decode(seed):
    rng = np.random.default_rng(seed)
    st = _rand_lowstate(rng)
    sdk_crc = CRC()
    # (a) our CRC is the SDK's, also over a random (unsealed) crc field.
    assert ll.crc32(st) == sdk_crc.Crc(st)
    ll.seal(st)
    assert st.crc == sdk_crc.Crc(st)
    assert ll.crc_ok(st)
    # (b) the fast encoder writes the SDK serialiser's bytes.
    sdk_bytes = st.serialize()
    assert sdk_bytes[:4] == CDR_HEADER_LE
    ll.fast_wire(st)
    assert st.serialize() == sdk_bytes
    assert st.serialize() == type(st).serialize(st)
    # XCDR2 requests go the SDK's way.
    assert st.serialize(use_version_2=True) == type(st).serialize(st, use_version_2=True)
    # (c) decoding gives the values (float32 on the wire) and a valid CRC.
    v = ll.decode_lowstate(sdk_bytes)
    assert list(v) == list(ll.lowstate_values(LowState_.deserialize(sdk_bytes)))
    assert len(v) == len(ll.lowstate_values(st))
    for k, m in enumerate(st.motor_state):
        base = ll.ST_MOTOR0 + k * ll.ST_MOTOR_STRIDE
        assert v[base] == m.mode
        assert v[base + 1] == f32(m.q)
        assert v[base + 2] == f32(m.dq)
        assert v[base + 4] == f32(m.tau_est)
        assert v[base + 8] == m.temperature
    assert list(v[ll.ST_IMU : ll.ST_IMU + 4]) == [f32(x) for x in st.imu_state.quaternion]
    assert list(v[ll.ST_FOOT : ll.ST_FOOT + 4]) == list(st.foot_force)
    assert v[ll.ST_TICK] == st.tick
    assert v[-1] == st.crc
    assert ll.lowstate_crc_ok(v)
    flipped = _flip_motor_q_byte(sdk_bytes, st.motor_state[3].q)
    assert not ll.lowstate_crc_ok(ll.decode_lowstate(flipped))
    # (d) our view of the decoded bytes is our view of the message.
    a = ll.read_lowstate_values(v)
    b = ll.read_lowstate(st)
    for name in ("q", "dq", "tau", "orientation", "angular_velocity", "linear_acceleration"):
        x, y = getattr(a, name), getattr(b, name)
        np.testing.assert_array_equal(x.astype(np.float32), y.astype(np.float32), err_msg=name)
    np.testing.assert_array_equal(a.foot_force, b.foot_force)
    assert a.tick == b.tick == st.tick
    assert a.q.shape == (N_LEG_JOINTS,)
    # Slot 0 (Unitree's FR hip) is our FR_abad; each slot lands on its joint.
    assert b.q[IDX["FR_abad"]] == st.motor_state[0].q
    assert a.q[IDX["FR_abad"]] == f32(st.motor_state[0].q)
    for r in jm.TABLE:
        assert b.q[IDX[r.joint]] == st.motor_state[r.motor].q
        assert b.dq[IDX[r.joint]] == st.motor_state[r.motor].dq
        assert b.tau[IDX[r.joint]] == st.motor_state[r.motor].tau_est


@pytest.mark.parametrize("seed", SEEDS)
def test_lowcmd_crc_serialise_decode(seed):
    rng = np.random.default_rng(100 + seed)
    cmd = _rand_lowcmd(rng)
    assert ll.crc32(cmd) == CRC().Crc(cmd)
    ll.seal(cmd)
    assert cmd.crc == CRC().Crc(cmd)
    sdk_bytes = type(cmd).serialize(cmd)
    ll.fast_wire(cmd)
    assert cmd.serialize() == sdk_bytes
    v = ll.decode_lowcmd(sdk_bytes)
    assert list(v) == list(ll.lowcmd_values(LowCmd_.deserialize(sdk_bytes)))
    for k, m in enumerate(cmd.motor_cmd):
        base = ll.CMD_MOTOR0 + k * ll.CMD_MOTOR_STRIDE
        assert v[base] == m.mode
        assert list(v[base + 1 : base + 6]) == [f32(x) for x in (m.q, m.dq, m.tau, m.kp, m.kd)]
    assert v[-1] == cmd.crc
    assert ll.lowcmd_crc_ok(v)
    flipped = _flip_motor_q_byte(sdk_bytes, cmd.motor_cmd[5].q)
    assert not ll.lowcmd_crc_ok(ll.decode_lowcmd(flipped))


def test_decode_rejects_wrong_header_and_crc_wrong_type():
    st = ll.new_lowstate()
    data = st.serialize()
    cmd_data = ll.new_lowcmd(np.arange(N_LEG_JOINTS)).serialize()
    big_endian = b"\x00\x00\x00\x00"
    with pytest.raises(ValueError):
        ll.decode_lowstate(big_endian + data[4:])
    with pytest.raises(ValueError):
        ll.decode_lowcmd(big_endian + cmd_data[4:])
    with pytest.raises(TypeError):
        ll.crc32(object())  # type: ignore[arg-type]


def test_new_lowcmd_stops_unused_slots():
    cmd = ll.new_lowcmd(np.arange(N_LEG_JOINTS))
    assert list(cmd.head) == list(ll.HEAD)
    assert cmd.level_flag == ll.LEVEL_LOW
    for i, m in enumerate(cmd.motor_cmd):
        assert m.mode == (ll.MOTOR_SERVO if i < N_LEG_JOINTS else ll.MOTOR_OFF)
        assert m.q == ll.POS_STOP_F and m.dq == ll.VEL_STOP_F
        assert m.kp == m.kd == m.tau == 0.0


def test_lowcmd_writer_fills_the_right_slots():
    rng = np.random.default_rng(11)
    q, dq, tau = rng.uniform(-2, 2, (3, N_LEG_JOINTS))
    kp, kd = rng.uniform(0, 100, N_LEG_JOINTS), rng.uniform(0, 5, N_LEG_JOINTS)
    w = ll.LowCmdWriter()
    cmd = w.fill(MotorTargets(q, dq, kp, kd, tau, LegMode.ACTIVE))
    assert cmd is w.cmd
    for r in jm.TABLE:
        i, m = IDX[r.joint], cmd.motor_cmd[r.motor]
        assert m.mode == ll.MOTOR_SERVO
        assert (m.q, m.dq, m.kp, m.kd, m.tau) == (q[i], dq[i], kp[i], kd[i], tau[i])
    assert cmd.motor_cmd[0].q == q[IDX["FR_abad"]]
    assert cmd.motor_cmd[4].kp == kp[IDX["FL_hip"]]
    for m in cmd.motor_cmd[N_LEG_JOINTS:]:
        assert m.mode == ll.MOTOR_OFF
        assert m.q == ll.POS_STOP_F and m.dq == ll.VEL_STOP_F
        assert m.kp == m.kd == m.tau == 0.0
    # Sealed with the SDK's CRC; the fast bytes are the SDK's and decode with a valid CRC.
    assert cmd.crc == CRC().Crc(cmd)
    data = cmd.serialize()
    assert data == type(cmd).serialize(cmd)
    assert ll.lowcmd_crc_ok(ll.decode_lowcmd(data))
    # The same object is refilled (and resealed) on the next call.
    cmd2 = w.fill(MotorTargets(-q, dq, kp, kd, tau, LegMode.ACTIVE))
    assert cmd2 is cmd
    assert cmd.motor_cmd[0].q == -q[IDX["FR_abad"]]
    assert cmd.crc == CRC().Crc(cmd)


def test_lowcmd_writer_with_signs_and_offsets():
    rows = _custom_rows()
    lm = LegJointMap(rows)
    rng = np.random.default_rng(12)
    q, dq, tau = rng.uniform(-2, 2, (3, N_LEG_JOINTS))
    kp, kd = rng.uniform(0, 100, N_LEG_JOINTS), rng.uniform(0, 5, N_LEG_JOINTS)
    cmd = ll.LowCmdWriter(lm).fill(MotorTargets(q, dq, kp, kd, tau, LegMode.ACTIVE))
    used = {r.motor for r in rows}
    for r in rows:
        i, m = IDX[r.joint], cmd.motor_cmd[r.motor]
        assert m.q == pytest.approx(r.sign * q[i] + r.offset, abs=1e-12)
        assert m.dq == pytest.approx(r.sign * dq[i], abs=1e-12)
        assert m.tau == pytest.approx(r.sign * tau[i], abs=1e-12)
        assert (m.kp, m.kd) == (kp[i], kd[i])
    for k, m in enumerate(cmd.motor_cmd):
        if k not in used:
            assert m.mode == ll.MOTOR_OFF and m.q == ll.POS_STOP_F
    assert ll.crc_ok(cmd)


# ------------------------------------------------------------------------- leg safety
@pytest.fixture(scope="module")
def limits():
    return rd.leg_joint_limits()


@pytest.fixture
def safety(limits):
    return LegSafety(LegSafetyConfig(), *limits)


def _state(limits, seed=0):
    lo, hi, _ = limits
    rng = np.random.default_rng(seed)
    q = lo + rng.uniform(0.3, 0.7, N_LEG_JOINTS) * (hi - lo)
    dq = rng.uniform(-0.5, 0.5, N_LEG_JOINTS)
    return q, dq


def _gentle_cmd(limits, q, dq):
    """A command well inside every limit at the state (q, dq)."""
    _, _, tau_max = limits
    c = LegSafetyConfig()
    kp = np.full(N_LEG_JOINTS, 0.1 * c.kp_max)
    kd = np.full(N_LEG_JOINTS, 0.1 * c.kd_max)
    q_des = q + 0.01
    dq_des = dq * 0.5
    pd = kp * (q_des - q) + kd * (dq_des - dq)
    ff = 0.1 * tau_max
    assert np.all(np.abs(pd + ff) < tau_max)
    return q_des, dq_des, kp, kd, ff


def _assert_damping(t, safety, q, mode=LegMode.DAMPING):
    assert t.mode is mode
    np.testing.assert_array_equal(t.kp, 0.0)
    np.testing.assert_array_equal(t.kd, safety.config.damping_kd)
    np.testing.assert_array_equal(t.tau, 0.0)
    np.testing.assert_array_equal(t.dq, 0.0)
    np.testing.assert_array_equal(t.q, q)


def test_safety_starts_in_damping(safety, limits):
    q, dq = _state(limits)
    _assert_damping(safety.targets(0.0, q, dq), safety, q)
    assert safety.mode is LegMode.DAMPING
    assert safety.timeouts == 0


def test_safety_passes_a_valid_command(safety, limits):
    q, dq = _state(limits)
    cmd = _gentle_cmd(limits, q, dq)
    assert safety.command(1.0, *cmd) == ""
    t = safety.targets(1.0, q, dq)
    assert t.mode is LegMode.ACTIVE
    for got, want in zip((t.q, t.dq, t.kp, t.kd, t.tau), cmd, strict=True):
        np.testing.assert_array_equal(got, want)
    assert safety.clamped == 0


def test_safety_clamps_position_and_gains(safety, limits):
    lo, hi, _ = limits
    q, dq = _state(limits)
    q_des, dq_des, kp, kd, ff = _gentle_cmd(limits, q, dq)
    c = safety.config
    q_des = q_des.copy()
    q_des[::2] = hi[::2] + 0.5
    q_des[1::2] = lo[1::2] - 0.5
    kp_big = np.full(N_LEG_JOINTS, 2 * c.kp_max)
    kd_big = np.full(N_LEG_JOINTS, 2 * c.kd_max)
    assert safety.command(0.0, q_des, dq_des, kp_big, kd_big, np.zeros(N_LEG_JOINTS)) == ""
    t = safety.targets(0.0, q, dq)
    assert t.mode is LegMode.ACTIVE
    np.testing.assert_array_equal(t.q[::2], hi[::2])
    np.testing.assert_array_equal(t.q[1::2], lo[1::2])
    np.testing.assert_array_equal(t.kp, c.kp_max)
    np.testing.assert_array_equal(t.kd, c.kd_max)
    assert safety.clamped == 1


def test_safety_limits_pd_plus_feedforward_torque(safety, limits):
    lo, hi, tau_max = limits
    q, dq = _state(limits, seed=1)
    rng = np.random.default_rng(5)
    c = safety.config
    kp = np.full(N_LEG_JOINTS, c.kp_max / 2)
    kd = np.full(N_LEG_JOINTS, c.kd_max / 2)
    # Some joints want more than tau_max from PD alone, others from ff, a few are fine.
    q_des = q + rng.choice([-1.0, 1.0], N_LEG_JOINTS) * rng.uniform(0.0, 0.5, N_LEG_JOINTS)
    q_des = np.clip(q_des, lo, hi)  # positions within range: only the torque is at stake
    dq_des = dq + rng.uniform(-1, 1, N_LEG_JOINTS)
    ff = rng.choice([-1.0, 1.0], N_LEG_JOINTS) * tau_max * rng.uniform(0.2, 1.0, N_LEG_JOINTS)
    ff[:2] = 0.0
    q_des[:2] = q[:2]
    dq_des[:2] = dq[:2]  # joints 0, 1: no torque at all, must stay untouched
    pd = kp * (q_des - q) + kd * (dq_des - dq)
    over = np.abs(pd + ff) > tau_max
    assert over.any() and not over.all()
    assert safety.command(0.0, q_des, dq_des, kp, kd, ff) == ""
    t = safety.targets(0.0, q, dq)
    assert t.mode is LegMode.ACTIVE
    total = t.kp * (t.q - q) + t.kd * (t.dq - dq) + t.tau
    assert np.all(np.abs(total) <= tau_max + 1e-9)
    # Saturated joints get exactly the limit, in the direction the command asked for;
    # the others get what they asked for.
    np.testing.assert_allclose(total[over], np.sign(pd + ff)[over] * tau_max[over], atol=1e-9)
    np.testing.assert_allclose(total[~over], (pd + ff)[~over], atol=1e-9)
    np.testing.assert_array_equal(t.tau[~over], ff[~over])
    np.testing.assert_array_equal(t.tau[:2], 0.0)
    # Only the feed-forward changed; the PD targets pass through.
    np.testing.assert_array_equal(t.q, q_des)
    np.testing.assert_array_equal(t.dq, dq_des)
    np.testing.assert_array_equal(t.kp, kp)
    np.testing.assert_array_equal(t.kd, kd)
    assert safety.clamped == 1


def test_safety_feedforward_alone_never_beyond_tau_max(safety, limits):
    _, _, tau_max = limits
    q, dq = _state(limits, seed=2)
    z = np.zeros(N_LEG_JOINTS)
    ff = 3.0 * tau_max * np.where(np.arange(N_LEG_JOINTS) % 2, 1.0, -1.0)
    kp = np.full(N_LEG_JOINTS, 1.0)
    assert safety.command(0.0, q, dq, kp, z, ff) == ""  # PD 0 at the measured state
    t = safety.targets(0.0, q, dq)
    np.testing.assert_allclose(t.tau, np.sign(ff) * tau_max, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "bad",
    ["nan", "inf", "shape", "negative_kp", "negative_kd", "strings"],
)
def test_safety_refuses_bad_commands(safety, limits, bad):
    q, dq = _state(limits)
    good = _gentle_cmd(limits, q, dq)
    assert safety.command(0.0, *good) == ""
    args = [a.copy() for a in good]
    if bad == "nan":
        args[0][3] = np.nan
    elif bad == "inf":
        args[4][7] = np.inf
    elif bad == "shape":
        args[1] = np.zeros(N_LEG_JOINTS + 1)
    elif bad == "negative_kp":
        args[2][0] = -1.0
    elif bad == "negative_kd":
        args[3][11] = -0.1
    elif bad == "strings":
        args[2] = np.array(["x"] * N_LEG_JOINTS)
    reason = safety.command(0.01, *args)
    assert reason
    assert safety.rejected == 1
    assert safety.last_reject == reason
    # The previous command stays in force (and its age is that of the good one).
    t = safety.targets(0.01, q, dq)
    assert t.mode is LegMode.ACTIVE
    for got, want in zip((t.q, t.dq, t.kp, t.kd, t.tau), good, strict=True):
        np.testing.assert_array_equal(got, want)


def test_safety_times_out_to_damping(safety, limits):
    q, dq = _state(limits)
    timeout = safety.config.timeout
    now = 12.5
    assert safety.command(now, *_gentle_cmd(limits, q, dq)) == ""
    assert safety.targets(now, q, dq).mode is LegMode.ACTIVE
    assert safety.targets(now + timeout - 0.001, q, dq).mode is LegMode.ACTIVE
    t = safety.targets(now + timeout + 0.001, q, dq)
    _assert_damping(t, safety, q)
    assert safety.timeouts == 1
    safety.targets(now + timeout + 0.002, q, dq)
    assert safety.timeouts == 1  # counted once


def test_safety_estop_latches(safety, limits):
    q, dq = _state(limits)
    cmd = _gentle_cmd(limits, q, dq)
    assert safety.command(0.0, *cmd) == ""
    assert safety.targets(0.0, q, dq).mode is LegMode.ACTIVE
    safety.engage_estop("test")
    assert safety.estop_reason == "test"
    _assert_damping(safety.targets(0.0, q, dq), safety, q, LegMode.ESTOP)
    # Fresh, valid commands do not release it.
    for k in range(1, 4):
        now = 0.002 * k
        assert safety.command(now, *cmd) == ""
        _assert_damping(safety.targets(now, q, dq), safety, q, LegMode.ESTOP)
    assert safety.timeouts == 0  # an e-stop is not a timeout
    safety.reset_estop()
    assert safety.estop_reason is None
    _assert_damping(safety.targets(0.01, q, dq), safety, q, LegMode.DAMPING)
    assert safety.command(0.012, *cmd) == ""
    t = safety.targets(0.012, q, dq)
    assert t.mode is LegMode.ACTIVE
    np.testing.assert_array_equal(t.kp, cmd[2])


def test_safety_config_and_limits_validated(limits):
    lo, hi, tau = limits
    with pytest.raises(ValueError):
        LegSafetyConfig(timeout=0.0)
    with pytest.raises(ValueError):
        LegSafetyConfig(kp_max=0.0)
    with pytest.raises(ValueError):
        LegSafety(LegSafetyConfig(), hi, lo, tau)
    with pytest.raises(ValueError):
        LegSafety(LegSafetyConfig(), lo[:-1], hi[:-1], tau[:-1])
    with pytest.raises(ValueError):
        LegSafety(LegSafetyConfig(), lo, hi, -tau)


# -------------------------------------------------------------- actuator_commands
def test_leg_watchdog_transitions():
    timeout = 0.05
    wd = LegWatchdog(timeout)
    assert wd.update(0.0) is LegMode.DAMPING
    assert wd.update(10.0) is LegMode.DAMPING
    assert wd.timeouts == 0  # damping before any command is no timeout
    wd.command(1.0)
    assert wd.mode_at(1.0 + timeout) is LegMode.ACTIVE  # inclusive
    assert wd.mode_at(1.0 + timeout + 1e-6) is LegMode.DAMPING
    assert wd.mode is LegMode.DAMPING  # mode_at has no side effects
    assert wd.update(1.0) is LegMode.ACTIVE
    assert wd.update(1.0 + timeout / 2) is LegMode.ACTIVE
    assert wd.update(1.0 + 2 * timeout) is LegMode.DAMPING
    assert wd.timeouts == 1
    assert wd.update(1.0 + 3 * timeout) is LegMode.DAMPING
    assert wd.timeouts == 1
    wd.command(2.0)
    assert wd.update(2.0) is LegMode.ACTIVE
    assert wd.update(3.0) is LegMode.DAMPING
    assert wd.timeouts == 2
    # E-stop: at once, latched, not a timeout; reset waits for a fresh command.
    wd.command(4.0)
    assert wd.update(4.0) is LegMode.ACTIVE
    wd.engage_estop("")
    assert wd.estop_reason  # an empty reason still latches
    assert wd.update(4.0) is LegMode.ESTOP
    wd.command(4.01)
    assert wd.update(4.01) is LegMode.ESTOP
    wd.reset_estop()
    assert wd.update(4.01) is LegMode.DAMPING
    assert wd.timeouts == 2
    wd.command(4.02)
    assert wd.update(4.02) is LegMode.ACTIVE
    with pytest.raises(ValueError):
        LegWatchdog(0.0)


def test_check_leg_command():
    z = np.zeros(N_LEG_JOINTS)
    cmd, reason = check_leg_command(z, z, z, z, z)
    assert reason == "" and cmd.shape == (5, N_LEG_JOINTS)
    src = np.ones(N_LEG_JOINTS)
    cmd, _ = check_leg_command(src, z, z, z, z)
    src[0] = 5.0
    assert cmd[0, 0] == 1.0  # a private copy
    for args in (
        (z[:-1], z, z, z, z),
        (z, z, -np.ones(N_LEG_JOINTS), z, z),
        (z, z, z, z, np.full(N_LEG_JOINTS, np.nan)),
    ):
        cmd, reason = check_leg_command(*args)
        assert cmd is None and reason


def _traj(t, q0=0.0, q1=1.0):
    n = len(t)
    q = np.linspace(q0, q1, n)[:, None] * np.ones((n, N_ARM_JOINTS))
    return dict(
        t=np.asarray(t, dtype=float),
        q=q,
        dq=np.zeros((n, N_ARM_JOINTS)),
        kp=np.full(N_ARM_JOINTS, 50.0),
        kd=np.full(N_ARM_JOINTS, 1.0),
    )


def test_check_arm_trajectory_accepts_and_copies():
    args = _traj([0.0, 1.0])
    seg, reason = check_arm_trajectory(**args)
    assert reason == "" and seg is not None
    assert seg.tau_ff is None  # zeros: none
    args["q"][0, 0] = 9.0
    assert seg.q[0, 0] == 0.0
    ff = np.ones((2, N_ARM_JOINTS))
    seg, _ = check_arm_trajectory(**_traj([0.0, 1.0]), tau_ff=ff)
    np.testing.assert_array_equal(seg.tau_ff, ff)
    seg1, reason = check_arm_trajectory(**_traj([3.0]))
    assert reason == "" and seg1 is not None


@pytest.mark.parametrize(
    "bad",
    [
        "t_equal",
        "t_decreasing",
        "t_nan",
        "q_nan",
        "dq_inf",
        "q_shape",
        "dq_rows",
        "kp_shape",
        "t_2d",
        "t_empty",
        "ff_shape",
        "negative_kd",
        "not_numbers",
    ],
)
def test_check_arm_trajectory_refusals(bad):
    a = _traj([0.0, 0.5, 1.0])
    kw = {}
    if bad == "t_equal":
        a["t"][2] = a["t"][1]
    elif bad == "t_decreasing":
        a["t"] = a["t"][::-1].copy()
    elif bad == "t_nan":
        a["t"][1] = np.nan
    elif bad == "q_nan":
        a["q"][1, 2] = np.nan
    elif bad == "dq_inf":
        a["dq"][0, 0] = np.inf
    elif bad == "q_shape":
        a["q"] = a["q"][:, :3]
    elif bad == "dq_rows":
        a["dq"] = a["dq"][:2]
    elif bad == "kp_shape":
        a["kp"] = np.ones(N_ARM_JOINTS + 1)
    elif bad == "t_2d":
        a["t"] = a["t"][:, None]
    elif bad == "t_empty":
        a = _traj([])
    elif bad == "ff_shape":
        kw["tau_ff"] = np.zeros((2, N_ARM_JOINTS))
    elif bad == "negative_kd":
        a["kd"][0] = -1.0
    elif bad == "not_numbers":
        a["q"] = [["a"] * N_ARM_JOINTS] * 3
    seg, reason = check_arm_trajectory(**a, **kw)
    assert seg is None
    assert isinstance(reason, str) and reason
    if bad in ("t_equal", "t_decreasing"):
        assert "increasing" in reason
    if bad in ("t_nan", "q_nan", "dq_inf"):
        assert "finite" in reason


def _seg(t0, t1):
    seg, reason = check_arm_trajectory(**_traj([t0, t1]))
    assert reason == ""
    return seg


def test_queue_segment_replaces_from_the_new_first_stamp():
    a, b = _seg(0.0, 1.0), _seg(2.0, 3.0)
    queue = queue_segment(queue_segment([], a), b)
    assert queue == [a, b]
    c = _seg(1.5, 4.0)
    queue = queue_segment(queue, c)
    assert queue == [a, c]  # b started after c: replaced
    d = _seg(1.5, 5.0)
    assert queue_segment(queue, d) == [a, d]  # same first stamp: replaced too
    e = _seg(-1.0, 0.5)
    assert queue_segment(queue, e) == [e]  # before everything: replaces all


def test_active_segment_drops_superseded_segments():
    a, c = _seg(0.0, 1.0), _seg(1.5, 4.0)
    queue = [a, c]
    assert active_segment(queue, -0.1) is None
    assert queue == [a, c]
    assert active_segment(queue, 0.0) is a
    assert active_segment(queue, 1.2) is a  # a ended, c not started: a still holds its end
    assert queue == [a, c]
    assert active_segment(queue, 1.5) is c
    assert queue == [c]  # a superseded, dropped
    assert active_segment(queue, 10.0) is c
    assert active_segment([], 0.0) is None


# --------------------------------------------------------------------- arm driver
Q0 = np.array([0.1, -0.4, 0.7, 0.0])
DT = 0.01


def test_arm_driver_holds_start_pose():
    drv = SimulatedArmDriver(Q0)
    for k in range(5):
        drv.update(k * DT)
        np.testing.assert_array_equal(drv.last.q, Q0)
        np.testing.assert_array_equal(drv.last.kp, drv.hold_kp)
        np.testing.assert_array_equal(drv.last.kd, drv.hold_kd)
        assert not drv.last.damping
    np.testing.assert_array_equal(drv.read().q, Q0)


def test_arm_driver_follows_a_trajectory_at_most_at_max_speed():
    drv = SimulatedArmDriver(Q0)
    q1 = Q0 + np.array([0.8, -0.6, 0.5, 1.2])
    t_end = 0.3  # faster than max_speed allows: the servos lag but never exceed it
    args = dict(
        t=[0.0, t_end],
        q=[Q0, q1],
        dq=np.zeros((2, N_ARM_JOINTS)),
        kp=np.full(N_ARM_JOINTS, 40.0),
        kd=np.full(N_ARM_JOINTS, 1.0),
    )
    assert drv.set_trajectory(0.0, args) == ""
    travel = float(np.max(np.abs(q1 - Q0)))
    n = int(np.ceil((t_end + travel / drv.max_speed) / DT)) + 5
    prev = drv.q.copy()
    for k in range(n):
        drv.update(k * DT)
        assert np.all(np.abs(drv.q - prev) <= drv.max_speed * DT + 1e-12)
        assert np.all(np.abs(drv.dq) <= drv.max_speed + 1e-9)
        prev = drv.q.copy()
    np.testing.assert_allclose(drv.q, q1, atol=1e-9)
    np.testing.assert_allclose(drv.last.q, q1, atol=1e-12)
    np.testing.assert_array_equal(drv.last.kp, args["kp"])


def test_arm_driver_refuses_nan_trajectory():
    drv = SimulatedArmDriver(Q0)
    q = np.array([Q0, Q0 + 0.1])
    q[1, 1] = np.nan
    args = dict(
        t=[0.0, 1.0],
        q=q,
        dq=np.zeros((2, N_ARM_JOINTS)),
        kp=np.ones(N_ARM_JOINTS),
        kd=np.ones(N_ARM_JOINTS),
    )
    reason = drv.set_trajectory(0.0, args)
    assert reason
    assert drv.rejected == 1 and drv.last_reject == reason
    for k in range(10):
        drv.update(k * DT)
    np.testing.assert_array_equal(drv.q, Q0)


def test_arm_driver_gripper_clip_and_slew():
    drv = SimulatedArmDriver(Q0, gap0=0.02)
    lo, hi = drv.gap_range
    assert drv.set_gripper(hi + 1.0, 10.0) == ""
    drv.update(0.0)
    assert drv.last.gripper_gap == hi
    assert drv.last.gripper_force == 10.0
    prev = drv.gap
    steps = int(np.ceil((hi - 0.02) / (drv.gap_speed * DT))) + 2
    for k in range(1, steps + 1):
        drv.update(k * DT)
        assert drv.gap - prev <= drv.gap_speed * DT + 1e-12
        prev = drv.gap
    assert drv.gap == pytest.approx(hi)
    assert drv.set_gripper(lo - 1.0, 5.0) == ""
    drv.update((steps + 1) * DT)
    assert drv.last.gripper_gap == lo
    assert drv.gap == pytest.approx(hi - drv.gap_speed * DT)
    assert drv.set_gripper(np.nan, 5.0)
    assert drv.set_gripper(0.05, -1.0)
    assert drv.rejected == 2


def test_arm_driver_estop():
    drv = SimulatedArmDriver(Q0)
    q1 = Q0 + 1.0
    args = dict(
        t=[0.0, 1.0],
        q=[Q0, q1],
        dq=np.zeros((2, N_ARM_JOINTS)),
        kp=np.full(N_ARM_JOINTS, 40.0),
        kd=np.full(N_ARM_JOINTS, 1.0),
    )
    assert drv.set_trajectory(0.0, args) == ""
    for k in range(20):
        drv.update(k * DT)
    moved = drv.q.copy()
    assert not np.allclose(moved, Q0)
    drv.engage_estop()
    drv.update(20 * DT)
    assert drv.last.damping
    np.testing.assert_array_equal(drv.last.kp, 0.0)
    np.testing.assert_array_equal(drv.last.kd, drv.damping_kd)
    np.testing.assert_array_equal(drv.q, moved)  # damped where it was
    assert drv.set_trajectory(20 * DT, {**args, "t": [0.2, 1.0]})
    assert drv.rejected == 1
    drv.update(21 * DT)
    assert drv.last.damping
    drv.reset_estop()
    for k in range(22, 30):
        drv.update(k * DT)
        assert not drv.last.damping
        np.testing.assert_array_equal(drv.last.q, moved)  # holds where it is
        np.testing.assert_array_equal(drv.last.kp, drv.hold_kp)
    np.testing.assert_array_equal(drv.q, moved)


# ------------------------------------------------------------------ sim e-stop
class _FloorWorld:
    """The robot alone on a floor: the smallest world a SimEngine accepts."""

    def __init__(self) -> None:
        self.model = rd.robot_only_with_floor()

    def initial_data(self) -> mujoco.MjData:
        d = mujoco.MjData(self.model)
        mujoco.mj_resetDataKeyframe(self.model, d, self.model.key(rd.HOME_KEY).id)
        return d


@pytest.fixture(scope="module")
def floor_world():
    return _FloorWorld()


def _leg_msg(eng, q_des):
    z = np.zeros(N_LEG_JOINTS)
    return msg.LegCommand(
        stamp=eng.time, tick=eng.tick, q_des=q_des, dq_des=z,
        kp=np.full(N_LEG_JOINTS, 50.0), kd=np.full(N_LEG_JOINTS, 1.0), tau_ff=z,
    )  # fmt: skip


def test_sim_actuators_obey_estop(floor_world):
    # Island sleeping off: with it, MuJoCo 4.0's mj_forward on robot_only_with_floor()
    # fails ("mju_makeFrame: xaxis of contact frame undefined"); the actuator layer is
    # the same either way.
    cfg = SimConfig(physics=PhysicsConfig(sleep=False))
    eng = SimEngine(floor_world, cfg, cameras=False, lidar=False, ground_truth=False)
    act, d = eng.actuators, eng.data
    kd = cfg.actuators.leg_damping_kd
    legs = act.legs
    q_home = d.qpos[legs.qpos].copy()
    dq_set = np.linspace(-1.0, 1.0, N_LEG_JOINTS)
    assert np.all(np.abs(kd * dq_set) < legs.tau_max)  # damping torque below the clamp

    def step_with(dq):
        d.qvel[legs.dof] = dq
        eng.physics_step()
        return act.tau[legs.act].copy()

    assert eng.apply_leg_command(_leg_msg(eng, q_home))
    step_with(dq_set)
    assert act.leg_mode is LegMode.ACTIVE
    act.engage_estop("test")
    tau = step_with(dq_set)
    assert act.leg_mode is LegMode.ESTOP
    np.testing.assert_allclose(tau, -kd * dq_set, rtol=0, atol=1e-12)
    # Fresh commands do not release it.
    for _ in range(3):
        assert eng.apply_leg_command(_leg_msg(eng, q_home))
        tau = step_with(dq_set)
        assert act.leg_mode is LegMode.ESTOP
        np.testing.assert_allclose(tau, -kd * dq_set, rtol=0, atol=1e-12)
    assert act.leg_timeouts == 0
    act.reset_estop()
    tau = step_with(dq_set)
    assert act.leg_mode is LegMode.DAMPING
    np.testing.assert_allclose(tau, -kd * dq_set, rtol=0, atol=1e-12)
    assert eng.apply_leg_command(_leg_msg(eng, q_home))
    step_with(dq_set)
    assert act.leg_mode is LegMode.ACTIVE
