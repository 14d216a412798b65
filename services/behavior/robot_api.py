"""How the tidy-up task talks to the robot: :class:`RobotApi` and what it answers.

The node implements it over the other services' actions and topics
(:class:`~quadmanip.services.behavior.node.BusRobot`); the unit tests with a simulated
house. Positions are in the ``map`` frame unless a field says otherwise.

The robot's services can die and be restarted by the launcher in the middle of a task.
:meth:`RobotApi.outages` counts, per service, how often it stopped running; a request to a
service that went away (or, for every request, locomotion: the robot lies down) ends at
once with ``Outcome.interrupted`` naming it. The rest is what the task needs to get going
again: :meth:`RobotApi.wait_for_services`, :meth:`RobotApi.stand_up`,
:meth:`RobotApi.localised` and :meth:`RobotApi.forget_objects`.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

from quadmanip.services.behavior.frames import BasePose, Point3, Pose2

__all__ = ["GraspPlan", "HandlePlan", "Outcome", "RobotApi", "SeenObject"]


@dataclass(frozen=True)
class Outcome:
    """How one request to the robot ended: ``ok``, else why (``rejected``: refused before
    anything moved, e.g. a grasp out of reach; ``interrupted``: the service that went away
    while it ran, or before it could be sent)."""

    ok: bool
    reason: str = ""
    rejected: bool = False
    interrupted: str = ""


@dataclass(frozen=True)
class SeenObject:
    """One object of perception's memory, in the map frame."""

    track_id: int
    label: str
    position: Point3
    confirmed: bool = True
    confidence: float = 1.0


@dataclass(frozen=True)
class GraspPlan:
    """Perception's grasp for manipulation: the grasp in the level body frame of the base
    pose it was estimated from (``seen_from``, odom), and where the grasp point is in the
    map (``position_map``: what the task steps around)."""

    position: Point3
    yaw: float
    approach: str
    width: float
    object_name: str
    seen_from: BasePose
    position_map: Point3
    tilt: float = 0.0
    mass: float = 0.0
    hang: float = 0.0
    center: Point3 | None = None  # the object's middle (frame of ``position``; None: unknown)


@dataclass(frozen=True)
class HandlePlan:
    """A located drawer handle (level body frame) and how far to pull it."""

    position: Point3
    pull_direction: Point3
    distance: float


class RobotApi(Protocol):
    """What the task asks of the robot. Every request blocks until it ends, but a posture
    move that is asked not to wait (:meth:`move_to_posture`)."""

    def now(self) -> float:
        """Robot time (s)."""
        ...

    def wait(self, seconds: float) -> None:
        """Let ``seconds`` of robot time pass (the cameras keep looking)."""
        ...

    def pose(self) -> Pose2 | None:
        """Where navigation believes the base is in the map (None: not localised)."""
        ...

    def objects(self) -> list[SeenObject]:
        """Perception's object memory, map frame."""
        ...

    def seen(
        self, points: Sequence[tuple[float, float]], table: bool, since: float = -math.inf
    ) -> list[bool] | None:
        """Whether perception's cameras have shown each map point's cell of floor (of a
        table top when ``table``) within the range its detector finds objects, and looked
        at it again at or after robot time ``since``; None when perception has said
        nothing of it."""
        ...

    def holding(self) -> bool | None:
        """Whether the gripper holds something (None: not known, e.g. since manipulation
        restarted)."""
        ...

    # ------------------------------------------------------------------ services
    def outages(self) -> Mapping[str, int]:
        """Per watched service, how many times it stopped running (died, was killed, went
        silent) since the node started; a restart under way counts already."""
        ...

    def wait_for_services(self, services: Collection[str], timeout: float) -> bool:
        """Block until every one of ``services`` runs again (True), or ``timeout`` s of wall
        time passed (False): robot time may stand still meanwhile (a lockstep sim waits for
        locomotion)."""
        ...

    def stand_up(self) -> Outcome:
        """Have locomotion stand the robot up (``recover`` first when it is tripped or lies
        on a side) and block until it stands."""
        ...

    def localised(self) -> bool:
        """Navigation reports a settled pose (localised, or mapping) from its current run."""
        ...

    def forget_objects(self) -> None:
        """From now on, :meth:`objects` leaves out what perception last saw before now (its
        memory is gone, or the odom frame it was kept in was restarted)."""
        ...

    def navigate_to(
        self, place: str = "", pose: Pose2 | None = None, lead_in: bool = False
    ) -> Outcome:
        """Walk to a named place of the places file, else to a map pose. ``lead_in``: an
        approach follows, so the walk may end loosely and still moving (the config's
        lead-in tolerances)."""
        ...

    def approach(
        self,
        target: tuple[float, float],
        standoff: float,
        heading: float | None = None,
        loose: bool = False,
        turn_free: bool = False,
    ) -> Outcome:
        """Stand so that map point ``target`` lies ``standoff`` m straight ahead, facing
        ``heading`` (map, rad) or, when None, facing the target (Algorithm 5); to the
        probing tolerance, or the looser stand tolerance when ``loose`` (a place's stand:
        the place plans from wherever the robot stands). ``turn_free``: navigation may
        turn the stance about the target off ``heading`` to stand clear of furniture
        (a table's leg; ``ApproachGoal.turn_free``)."""
        ...

    def move_to_posture(self, posture: str, wait: bool = True) -> Outcome:
        """Move the arm to a named posture. ``wait=False``: send the move and return at
        once (ok) while the arm moves, so a walk can start meanwhile; the next arm or
        camera request (a posture, an estimate, a grasp, a place, a handle, a drawer) waits
        for it to end first, and sends it once more, blocking, if it failed."""
        ...

    def wait_for_arm(self) -> Outcome:
        """Wait for a posture move sent without waiting to end (ok at once when none): the
        cameras look from the posture itself from then on."""
        ...

    def estimate_grasp(
        self, label: str, camera: str, track_id: int = -1
    ) -> tuple[Outcome, GraspPlan | None]:
        """Perception's grasp of an object (a track, else the best-seen of a class)."""
        ...

    def grasp(self, plan: GraspPlan) -> Outcome:
        """Grasp and lift (Algorithm 6), the plan carried over to the current stance."""
        ...

    def place(self, position: Point3, yaw: float | None = None) -> Outcome:
        """Place the held object at map point ``position``, the gripper turned to ``yaw``
        (the grasp's convention, 0 = fingers along the body y) or as it is (None)."""
        ...

    def locate_handle(self, hint: Point3, distance: float) -> tuple[Outcome, HandlePlan | None]:
        """The drawer handle near map point ``hint``, to be pulled ``distance`` m."""
        ...

    def open_drawer(self, handle: HandlePlan) -> Outcome:
        """Pull the handle open."""
        ...
