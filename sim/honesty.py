"""The honesty guard: proof, during every run, that only physics moved the robot and objects.

The simulator stands in for a real robot (docs/architecture.md, "Honest simulation"): after a
scenario is loaded, the robot and the objects move only by actuator torques, contacts and
gravity. :class:`HonestyGuard` looks for every MuJoCo mechanism that could move them
otherwise and keeps a deduplicated list of what it found, with counts and the sim time of
the first trip. The engine builds one per run, checks it before every physics step and
hands :meth:`HonestyGuard.violations` to the judge's report.

Checked once, at construction (the model's structure; "watched" = every body of the robot's
kinematic tree and of each object's):

* mocap bodies among the watched bodies (a mocap body is moved by assignment, not physics);
* equality constraints of every type (connect, weld, joint, tendon, flex...) that involve a
  watched body, through the bodies, sites, joints, tendons, geoms or flexes they reference.
  The one exception is the gripper's internal finger coupling (the joint equality between
  the two :data:`~quadmanip.common.robot_description.GRIPPER_JOINTS`), found by its joints.
  Active at load or switched on later in ``eq_active``, they are violations;
* gravity compensation on a watched body (an upward force from nowhere);
* actuators acting on an object, adhesion actuators on the robot, and site transmissions
  without a reference site on the robot (thrusters: forces without a reaction body);
* tendons that tie a watched tree to anything outside it (a leash or a rope to the world);

and before every physics step (what the step is about to integrate):

* ``xfrc_applied`` holds exactly what the test-only disturbance channel wrote (zero when it
  is idle or absent);
* ``qfrc_applied`` is zero (nothing in the simulator writes it);
* no equality that involves a watched body was switched on in ``eq_active``;
* no collidable mocap body (a kinematic pusher) moved from its load pose.

Cost: on the ``paper-1`` world (46 bodies, 87 dofs, objects awake) one honest
:meth:`HonestyGuard.check` takes 2.1 us (timeit, 200k calls, three repeats, on the shared
2-core development machine), against 205-215 us for the physics step itself: about 1 %.
(``np.count_nonzero`` instead of ``ndarray.any()`` took it from 5.2 us to 2.1 us.) So it
runs before every physics step rather than once per control tick: a foreign write into
``xfrc_applied`` can be overwritten by the channel at the next step, so a per-tick check
could miss a push that one step integrated, and a per-step check costs next to nothing.

The guard only detects; it never undoes a write (a tripped run is invalid anyway, and the
record says what happened and when). Teleporting through ``qpos`` is covered by the
engine's tests, not here.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from quadmanip.common.log import get_logger
from quadmanip.common.robot_description import GRIPPER_JOINTS
from quadmanip.sim.disturbance import DisturbanceChannel

log = get_logger("sim.honesty")

_OBJ = mujoco.mjtObj
_WRAP = mujoco.mjtWrap
_TRN = mujoco.mjtTrn
_EQ = mujoco.mjtEq
# What eq_obj1id/eq_obj2id refer to, per equality type; connect and weld say it in
# eq_objtype (body or site), the others leave eq_objtype at mjOBJ_UNKNOWN.
_EQ_OBJTYPE = {
    int(_EQ.mjEQ_JOINT): int(_OBJ.mjOBJ_JOINT),
    int(_EQ.mjEQ_TENDON): int(_OBJ.mjOBJ_TENDON),
    int(_EQ.mjEQ_FLEX): int(_OBJ.mjOBJ_FLEX),
    int(_EQ.mjEQ_FLEXVERT): int(_OBJ.mjOBJ_FLEX),
    int(_EQ.mjEQ_FLEXSTRAIN): int(_OBJ.mjOBJ_FLEX),
    int(_EQ.mjEQ_DISTANCE): int(_OBJ.mjOBJ_GEOM),
}


@dataclass
class _Record:
    what: str
    first: float  # sim time (s since load) of the first trip
    count: int  # steps seen (1 for a structural finding)
    per_step: bool


def _name(m: mujoco.MjModel, obj: int, i: int) -> str:
    return mujoco.mj_id2name(m, obj, i) or f"#{i}"


def _body_name(m: mujoco.MjModel, b: int) -> str:
    return "world" if b == 0 else (m.body(b).name or f"body{b}")


def _tendon_bodies(m: mujoco.MjModel, t: int) -> set[int]:
    """The bodies a tendon pulls on: joints' bodies, sites' bodies, wrapping geoms' bodies."""
    out: set[int] = set()
    for w in range(m.tendon_adr[t], m.tendon_adr[t] + m.tendon_num[t]):
        kind, i = int(m.wrap_type[w]), int(m.wrap_objid[w])
        if i < 0:
            continue
        if kind == _WRAP.mjWRAP_JOINT:
            out.add(int(m.jnt_bodyid[i]))
        elif kind == _WRAP.mjWRAP_SITE:
            out.add(int(m.site_bodyid[i]))
        elif kind in (_WRAP.mjWRAP_SPHERE, _WRAP.mjWRAP_CYLINDER):
            out.add(int(m.geom_bodyid[i]))
    return out


def _flex_bodies(m: mujoco.MjModel, f: int) -> set[int]:
    v0, n = int(m.flex_vertadr[f]), int(m.flex_vertnum[f])
    out = set(m.flex_vertbodyid[v0 : v0 + n].tolist())
    n0, nn = int(m.flex_nodeadr[f]), int(m.flex_nodenum[f])
    return out | set(m.flex_nodebodyid[n0 : n0 + nn].tolist())


def bodies_of(m: mujoco.MjModel, objtype: int, i: int) -> set[int] | None:
    """The bodies an element (body, site, joint, geom, tendon, flex) acts on; ``None`` for
    a kind this guard does not know, so its caller can treat it as suspect."""
    if i < 0:
        return set()
    if objtype in (_OBJ.mjOBJ_BODY, _OBJ.mjOBJ_XBODY):
        return {i}
    if objtype == _OBJ.mjOBJ_SITE:
        return {int(m.site_bodyid[i])}
    if objtype == _OBJ.mjOBJ_JOINT:
        return {int(m.jnt_bodyid[i])}
    if objtype == _OBJ.mjOBJ_GEOM:
        return {int(m.geom_bodyid[i])}
    if objtype == _OBJ.mjOBJ_TENDON:
        return _tendon_bodies(m, i)
    if objtype == _OBJ.mjOBJ_FLEX:
        return _flex_bodies(m, i)
    return None


class HonestyGuard:
    """Detects every non-physical way of moving the robot or the objects (see the module)."""

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        robot_bodies: Iterable[int],
        object_bodies: Iterable[int],
        disturbance: DisturbanceChannel | None = None,
        *,
        time_origin: float = 0.0,
        internal_couplings: Sequence[Sequence[str]] = (GRIPPER_JOINTS,),
    ) -> None:
        m = self.model = model
        self._disturbance = disturbance
        self._origin = float(time_origin)
        self._records: dict[str, _Record] = {}
        self.first_trip: float | None = None  # sim time (s since load) of the first trip

        root = m.body_rootid
        robot_roots = {int(root[b]) for b in robot_bodies}
        object_roots = {int(root[b]) for b in object_bodies}
        # The world body (root 0) is never watched: it is what others are held to.
        robot_roots.discard(0)
        object_roots.discard(0)
        self._robot = np.isin(root, list(robot_roots))
        self._object = np.isin(root, list(object_roots))
        self._watched = self._robot | self._object
        self._internal = {frozenset(pair) for pair in internal_couplings}

        self._scan_structure()
        # Equalities that involve a watched body: none may be active, at load or later.
        self._eq_watch = np.array([e for e in range(m.neq) if self._eq_forbidden(e)], dtype=int)
        # Collidable mocap bodies: moving one pushes things without physics.
        collidable = (m.geom_contype != 0) | (m.geom_conaffinity != 0)
        movers = {
            int(m.body_mocapid[m.geom_bodyid[g]])
            for g in np.flatnonzero(collidable)
            if m.body_mocapid[m.geom_bodyid[g]] >= 0
        }
        self._mocap_watch = np.array(sorted(movers), dtype=int)
        self._mocap_pos0 = data.mocap_pos[self._mocap_watch].copy()
        self._mocap_quat0 = data.mocap_quat[self._mocap_watch].copy()
        self._check_equalities(data)

    # ------------------------------------------------------------------ results
    @property
    def tripped(self) -> bool:
        """Whether anything dishonest was found (structure or run)."""
        return bool(self._records)

    def violations(self) -> list[str]:
        """Every distinct violation, once, in the order first seen, with its count and the
        sim time of its first occurrence (per-step findings)."""
        out = []
        for r in self._records.values():
            if r.per_step:
                out.append(f"{r.what}: {r.count} step(s) from t={r.first:.3f} s")
            else:
                out.append(r.what)
        return out

    def _record(self, what: str, data: mujoco.MjData | None, per_step: bool = True) -> None:
        r = self._records.get(what)
        if r is not None:
            r.count += 1
            return
        t = 0.0 if data is None else float(data.time) - self._origin
        self._records[what] = _Record(what, t, 1, per_step)
        if self.first_trip is None:
            self.first_trip = t
        log.error("honesty violation", what=what, t=round(t, 4))

    # --------------------------------------------------------------- per step
    def check(self, data: mujoco.MjData) -> bool:
        """The per-physics-step check, run before the step integrates; True when honest.

        The common, honest path is four vectorised tests of a few microseconds; the slow
        path (naming who was pushed or held) only runs on a violation.
        """
        ok = True
        dist = self._disturbance
        if dist is not None:
            if not dist.untouched_since_last_apply(data):
                ok = False
                self._foreign_xfrc(data, dist.foreign_bodies(data))
        elif np.count_nonzero(data.xfrc_applied):
            ok = False
            self._foreign_xfrc(data, np.flatnonzero(data.xfrc_applied.any(axis=1)))
        if np.count_nonzero(data.qfrc_applied):  # 3x cheaper than .any() here
            ok = False
            dofs = np.flatnonzero(data.qfrc_applied)
            bodies = sorted({int(b) for b in self.model.dof_bodyid[dofs]})
            self._record(f"generalized force (qfrc_applied) on {self._names(bodies)}", data)
        if self._eq_watch.size and data.eq_active[self._eq_watch].any():
            ok = False
            self._check_equalities(data)
        if self._mocap_watch.size and not (
            np.array_equal(data.mocap_pos[self._mocap_watch], self._mocap_pos0)
            and np.array_equal(data.mocap_quat[self._mocap_watch], self._mocap_quat0)
        ):
            ok = False
            self._moved_mocap(data)
        return ok

    def _foreign_xfrc(self, data: mujoco.MjData, bodies: np.ndarray) -> None:
        self._record(
            "external force (xfrc_applied) outside the disturbance channel on "
            f"{self._names(bodies.tolist())}",
            data,
        )

    def _moved_mocap(self, data: mujoco.MjData) -> None:
        m = self.model
        for k, i in enumerate(self._mocap_watch):
            if not (
                np.array_equal(data.mocap_pos[i], self._mocap_pos0[k])
                and np.array_equal(data.mocap_quat[i], self._mocap_quat0[k])
            ):
                b = int(np.flatnonzero(m.body_mocapid == i)[0])
                self._record(f"collidable mocap body {_body_name(m, b)!r} moved", data)

    def _check_equalities(self, data: mujoco.MjData) -> None:
        m = self.model
        for e in self._eq_watch:
            if data.eq_active[e]:
                kind = _EQ(int(m.eq_type[e])).name.removeprefix("mjEQ_").lower()
                bodies = self._eq_bodies(int(e))
                held = "unknown elements" if bodies is None else self._names(sorted(bodies))
                self._record(
                    f"{kind} equality {_name(m, _OBJ.mjOBJ_EQUALITY, e)!r} on {held}", data
                )

    # -------------------------------------------------------------- structure
    def _names(self, bodies: Iterable[int]) -> str:
        return ", ".join(repr(_body_name(self.model, b)) for b in bodies)

    def _eq_bodies(self, e: int) -> set[int] | None:
        m = self.model
        kind = _EQ_OBJTYPE.get(int(m.eq_type[e]), int(m.eq_objtype[e]))
        b1 = bodies_of(m, kind, int(m.eq_obj1id[e]))
        b2 = bodies_of(m, kind, int(m.eq_obj2id[e]))
        return None if b1 is None or b2 is None else b1 | b2

    def _eq_forbidden(self, e: int) -> bool:
        """Whether equality ``e`` involves a watched body and is not an internal coupling
        of the robot (the fingers); an equality on unknown elements counts as involved."""
        m = self.model
        if m.eq_type[e] == _EQ.mjEQ_JOINT:
            j1, j2 = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
            if j1 >= 0 and j2 >= 0:
                pair = frozenset((_name(m, _OBJ.mjOBJ_JOINT, j1), _name(m, _OBJ.mjOBJ_JOINT, j2)))
                if pair in self._internal:
                    return False
        bodies = self._eq_bodies(e)
        return bodies is None or bool(self._watched[list(bodies)].any())

    def _scan_structure(self) -> None:
        m = self.model
        for b in np.flatnonzero(self._watched):
            if m.body_mocapid[b] >= 0:
                who = "robot" if self._robot[b] else "object"
                self._record(f"mocap body {_body_name(m, b)!r} ({who})", None, per_step=False)
            if m.body_gravcomp[b] != 0:
                self._record(f"gravity compensation on {_body_name(m, b)!r}", None, per_step=False)
        for a in range(m.nu):
            self._scan_actuator(a)
        root = m.body_rootid
        for t in range(m.ntendon):
            bodies = _tendon_bodies(m, t)
            trees = {int(root[b]) for b in bodies}
            if self._watched[list(bodies)].any() and len(trees) > 1:
                self._record(
                    f"tendon {_name(m, _OBJ.mjOBJ_TENDON, t)!r} ties "
                    f"{self._names(sorted(bodies))} together",
                    None,
                    per_step=False,
                )

    def _scan_actuator(self, a: int) -> None:
        m = self.model
        kind = int(m.actuator_trntype[a])
        i1, i2 = (int(x) for x in m.actuator_trnid[a])
        objtype = {
            _TRN.mjTRN_JOINT: _OBJ.mjOBJ_JOINT,
            _TRN.mjTRN_JOINTINPARENT: _OBJ.mjOBJ_JOINT,
            _TRN.mjTRN_TENDON: _OBJ.mjOBJ_TENDON,
            _TRN.mjTRN_SITE: _OBJ.mjOBJ_SITE,
            _TRN.mjTRN_SLIDERCRANK: _OBJ.mjOBJ_SITE,
            _TRN.mjTRN_SO3: _OBJ.mjOBJ_SITE,
            _TRN.mjTRN_BODY: _OBJ.mjOBJ_BODY,
        }.get(kind)
        if objtype is None:
            return
        bodies = bodies_of(m, objtype, i1) or set()
        if kind in (_TRN.mjTRN_SITE, _TRN.mjTRN_SLIDERCRANK, _TRN.mjTRN_SO3):
            bodies |= bodies_of(m, objtype, i2) or set()
        if not bodies:
            return
        ids = sorted(bodies)
        name = _name(m, _OBJ.mjOBJ_ACTUATOR, a)
        if self._object[ids].any():
            what = f"actuator {name!r} acts on object {self._names(ids)}"
        elif kind == _TRN.mjTRN_BODY and self._robot[ids].any():
            what = f"adhesion actuator {name!r} on {self._names(ids)}"
        elif kind in (_TRN.mjTRN_SITE, _TRN.mjTRN_SO3) and i2 < 0 and self._robot[ids].any():
            what = f"actuator {name!r} pushes {self._names(ids)} with no reaction body"
        else:
            return
        self._record(what, None, per_step=False)
