"""The judge: from ground truth, which objects a referee would count as placed.

Paper Section 7.2: each object belongs in the place of its category (pencil case, tray,
drawer, green box, black box, small box). The paper counted an object whose centre lay in
a box reaching well above the place; a RoboCup@Home referee would not count one still in
the gripper over the box, one balanced on the rim, or one that bounced out again. So an
object is **placed** only when all of these hold:

1. its centre lies in the inner volume of one of its category's places (the drawer place:
   inside the drawer's box, however far the drawer is open), no higher than
   ``max(rim, inner bottom + half its longest side)`` plus a small tolerance, i.e. no
   higher above the rim than the object itself would stand inside;
2. it is supported by the place: in contact with the place's own geoms, or with another
   object that is itself placed there;
3. it touches no part of the robot;
4. it has been at rest (``rest_linear``, ``rest_angular``) for ``rest_time`` of sim time
   without interruption.

Otherwise the report says where it is (``JUDGE_LOCATIONS``): held (touching the robot), in
another category's place (a failure), on the floor, on furniture (tables, cabinet, walls,
a place's rim), or elsewhere, with a note saying which condition failed.

"At rest for a while" and contacts need history, so the judge is a small stateful
component: :meth:`Judge.track` runs at ``track_rate`` (a few array operations over the
contacts that involve objects) and :meth:`Judge.report` gives the verdict
whenever asked. MuJoCo drops the contacts of sleeping bodies (island sleeping), and a
sleeping body does not move, so the judge keeps the last contacts it saw an object make
while it slept. Only the sim (and tests) use this module: it reads ground truth, which no
service may.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from quadmanip.common.messages import JudgeReport
from quadmanip.common.robot_description import BASE_BODY
from quadmanip.sim.world.builder import World
from quadmanip.sim.world.house import DepositRegion

__all__ = ["Judge", "JudgeConfig", "highest_centre"]


@dataclass(frozen=True)
class JudgeConfig:
    """``[judge]`` in configs/sim.toml: what "at rest" and "placed" mean."""

    rest_linear: float = 0.01  # m/s: slower than this counts as at rest
    rest_angular: float = 0.2  # rad/s
    rest_time: float = 1.0  # s of sim time at rest, without interruption
    height_tolerance: float = 0.01  # m above the highest centre an object standing inside has
    # Hz (sim time) of rest and contact tracking: 10 ms resolution on "1 s at rest" for
    # ~75 us per sample with 10 objects awake (a fifth of the cost of every 2 ms tick).
    track_rate: float = 100.0


def highest_centre(bottom: float, rim: float, half_long: float, config: JudgeConfig) -> float:
    """Rule 1's upper bound on a placed object's centre: no higher above the rim than the
    object (half its longest side ``half_long``) would stand inside on the ``bottom``."""
    return max(rim, bottom + half_long) + config.height_tolerance


# Partner kinds of a contact, as seen from an object.
_ROBOT, _FLOOR, _FURNITURE = -1, -2, -3


class Judge:
    """Tracks rest and contacts of every object of ``world``; reports the verdict."""

    def __init__(self, world: World, config: JudgeConfig | None = None) -> None:
        self.world = world
        self.config = config or JudgeConfig()
        m = world.model
        self.model = m
        self.names: list[str] = list(world.object_names)
        n = len(self.names)
        self._bodies = np.array([world.object_body_ids[k] for k in self.names], dtype=int)
        dofs = [m.jnt_dofadr[m.joint(f"obj/{k}/free").id] for k in self.names]
        self._dof = (np.asarray(dofs, dtype=int)[:, None] + np.arange(6)).reshape(n, 6)
        # Longest side of each object: the highest its centre stands above a bottom is half.
        cat = world.catalogue.objects
        self._half_long = np.array([0.5 * max(cat[k].size) for k in self.names])
        self._place = [world.place_of(k) for k in self.names]
        self.regions: tuple[DepositRegion, ...] = tuple(world.regions)
        self._region_body = [-1 if r.body == "world" else m.body(r.body).id for r in self.regions]
        # What a geom is to an object: another object (its index), a place's support
        # (index into regions, offset), the robot, the floor, or furniture.
        obj_of_body = np.full(m.nbody, -1, dtype=int)
        obj_of_body[self._bodies] = np.arange(n)
        self._obj_of_body = obj_of_body
        kind = np.full(m.ngeom, _FURNITURE, dtype=int)
        body = m.geom_bodyid
        if world.robot:
            base = m.body(BASE_BODY).id
            robot = m.body_rootid[body] == m.body_rootid[base]
            kind[robot] = _ROBOT
        kind[(body == 0) & (m.geom_type == mujoco.mjtGeom.mjGEOM_PLANE)] = _FLOOR
        self._support_of_region = [m.body(r.support_body).id for r in self.regions]
        geom_region = np.full(m.ngeom, -1, dtype=int)
        for k, b in enumerate(self._support_of_region):
            geom_region[body == b] = k
        self._geom_region = geom_region
        self._geom_kind = kind
        self._geom_body = body.astype(int)
        self._rim = np.array([r.rim for r in self.regions])
        self._rest_since = np.full(n, np.nan)
        # Contacts per object (kept while the object sleeps): robot, floor, furniture (any
        # other static or jointed geom, places included), other objects, and the places
        # whose geoms hold it from inside (a contact below the rim, not on its top).
        nr = len(self.regions)
        self._robot = np.zeros(n, dtype=bool)
        self._floor = np.zeros(n, dtype=bool)
        self._furniture = np.zeros(n, dtype=bool)
        self._objects = np.zeros((n, n), dtype=bool)
        self._inner_support = np.zeros((n, nr), dtype=bool)

    #: A contact counts as holding an object from inside a place when it lies this far
    #: below the rim (a contact on the rim's top face does not: a bridge is not "in").
    RIM_MARGIN = 0.003

    # ------------------------------------------------------------------ tracking
    def reset(self) -> None:
        """Forget rest and contact history (a new trial)."""
        self._rest_since[:] = np.nan
        for a in (self._robot, self._floor, self._furniture, self._objects, self._inner_support):
            a[...] = False

    def track(self, data: mujoco.MjData) -> None:
        """Update rest timers and contacts from ``data`` (contacts current, as after
        ``mj_step1``/``mj_forward``/``mj_step``); call at ``config.track_rate``."""
        n = len(self.names)
        if n == 0:
            return
        t = float(data.time)
        v = data.qvel[self._dof]
        c = self.config
        rest = (np.linalg.norm(v[:, :3], axis=1) < c.rest_linear) & (
            np.linalg.norm(v[:, 3:], axis=1) < c.rest_angular
        )
        rs = self._rest_since
        rs[~rest] = np.nan
        rs[rest & np.isnan(rs)] = t
        nr = len(self.regions)
        robot = np.zeros(n, dtype=bool)
        floor = np.zeros(n, dtype=bool)
        furniture = np.zeros(n, dtype=bool)
        objects = np.zeros((n, n), dtype=bool)
        inner = np.zeros((n, nr), dtype=bool)
        ncon = data.ncon
        if ncon:
            geoms = data.contact.geom[:ncon]
            objs = self._obj_of_body[self._geom_body[geoms]]
            # Each contact seen from each object in it: (object, partner geom, contact).
            o = objs.T.reshape(-1)
            partner = geoms[:, ::-1].T.reshape(-1)
            ci = np.tile(np.arange(ncon), 2)
            keep = o >= 0
            o, partner, ci = o[keep], partner[keep], ci[keep]
            kind = self._geom_kind[partner]
            robot[o[kind == _ROBOT]] = True
            floor[o[kind == _FLOOR]] = True
            furniture[o[kind == _FURNITURE]] = True
            pobj = self._obj_of_body[self._geom_body[partner]]
            objects[o[pobj >= 0], pobj[pobj >= 0]] = True
            k = self._geom_region[partner]
            sel = k >= 0
            if sel.any():
                k, os_, pos = k[sel], o[sel], data.contact.pos[ci[sel]]
                z = np.empty(len(k))
                for j in range(len(k)):
                    b = self._region_body[k[j]]
                    if b < 0:
                        z[j] = pos[j, 2]
                    else:
                        rot = data.xmat[b].reshape(3, 3)
                        z[j] = (rot.T @ (pos[j] - data.xpos[b]))[2]
                below = z < self._rim[k] - self.RIM_MARGIN
                inner[os_[below], k[below]] = True
        if self.model.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_SLEEP):
            # A sleeping body has no contacts in MuJoCo and does not move: keep its last.
            asleep = data.body_awake[self._bodies] == 0
            robot[asleep] = self._robot[asleep]
            floor[asleep] = self._floor[asleep]
            furniture[asleep] = self._furniture[asleep]
            objects[asleep] = self._objects[asleep]
            inner[asleep] = self._inner_support[asleep]
        self._robot, self._floor, self._furniture = robot, floor, furniture
        self._objects, self._inner_support = objects, inner

    # ------------------------------------------------------------------- verdict
    def _frames(self, data: mujoco.MjData) -> list[tuple[np.ndarray, np.ndarray]]:
        out = []
        for b in self._region_body:
            if b < 0:
                out.append((np.zeros(3), np.eye(3)))
            else:
                out.append((data.xpos[b].copy(), data.xmat[b].reshape(3, 3).copy()))
        return out

    def _region_of(
        self, i: int, p: np.ndarray, frames: Sequence[tuple[np.ndarray, np.ndarray]]
    ) -> tuple[int | None, int | None]:
        """(own region containing object i's centre, another category's region)."""
        own = other = None
        for k, r in enumerate(self.regions):
            pos, rot = frames[k]
            local = rot.T @ (p - pos)
            top = highest_centre(r.bottom, r.rim, self._half_long[i], self.config)
            if r.contains_local(local, top=top):
                if r.place == self._place[i]:
                    own = k if own is None else own
                elif other is None:
                    other = k
        return own, other

    def report(
        self,
        data: mujoco.MjData,
        trial_start: float = 0.0,
        violations: Sequence[str] = (),
        leg_timeouts: int = 0,
    ) -> JudgeReport:
        """The verdict for the state in ``data`` (body poses current) with the history
        tracked so far; ``violations`` (the honesty guard's) make the trial invalid;
        ``leg_timeouts`` (the actuator layer's count) goes on the record."""
        n = len(self.names)
        t = float(data.time)
        c = self.config
        pos = data.xpos[self._bodies].reshape(n, 3).copy()
        rest_s = np.where(np.isnan(self._rest_since), 0.0, t - self._rest_since)
        frames = self._frames(data)
        regions = [self._region_of(i, pos[i], frames) for i in range(n)]
        held = self._robot
        rested = rest_s >= c.rest_time
        # Placed objects, to a fixed point: held from inside by the place, or resting on a
        # placed object in the same region.
        candidate = [
            regions[i][0] is not None and not held[i] and bool(rested[i]) for i in range(n)
        ]
        placed = [False] * n
        changed = True
        while changed:
            changed = False
            for i in range(n):
                if placed[i] or not candidate[i]:
                    continue
                k = regions[i][0]
                assert k is not None
                if self._inner_support[i, k] or any(
                    placed[j] and regions[j][0] == k for j in np.flatnonzero(self._objects[i])
                ):
                    placed[i] = changed = True
        locations, notes = [], []
        for i in range(n):
            own, other = regions[i]
            if placed[i]:
                loc, note = "in_place", ""
            elif held[i]:
                loc, note = "held", "touches the robot"
            elif other is not None:
                loc = "wrong_place"
                note = f"in {self.regions[other].name}; belongs in {self._place[i]}"
            elif own is not None and rest_s[i] < c.rest_time:
                loc = "elsewhere"
                note = f"in {self.regions[own].name}, at rest {rest_s[i]:.2f} s of {c.rest_time:g}"
            elif self._floor[i]:
                loc, note = "floor", f"belongs in {self._place[i]}"
            elif self._furniture[i]:
                loc = "furniture"
                note = (
                    f"on {self.regions[own].name}'s rim, not inside"
                    if own is not None
                    else f"belongs in {self._place[i]}"
                )
            elif own is not None:
                loc, note = "elsewhere", f"in {self.regions[own].name} but not supported by it"
            else:
                loc, note = "elsewhere", f"belongs in {self._place[i]}"
            locations.append(loc)
            notes.append(note)
        in_place = [k for k, ok in zip(self.names, placed, strict=True) if ok]
        return JudgeReport(
            stamp=t - trial_start,
            trial_time=t - trial_start,
            in_place=in_place,
            misplaced=[k for k, ok in zip(self.names, placed, strict=True) if not ok],
            total=n,
            objects=list(self.names),
            locations=locations,
            notes=notes,
            positions=pos,
            rest_s=rest_s,
            valid=not violations,
            violations=list(violations),
            leg_timeouts=int(leg_timeouts),
        )
