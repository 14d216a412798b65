"""Actions over the bus: long-running requests (go to pose, grasp, place, open a drawer).

An action is built from queryables and publications under ``<service>/action/<name>``;
its goal type is the key table's row (:class:`~quadmanip.common.keys.Action`):

* ``.../goal`` — the client sends :class:`ActionGoal` as the payload of a Zenoh query;
  the server's queryable answers with :class:`ActionResponse` (accepted, or rejected with
  a reason). Using a query, not a publication, means the client learns at once whether a
  server exists and accepted (no lost goal while subscriptions propagate; a timeout is
  reported as a rejection "no action server"). A session that has just opened may not
  know the server's queryable yet, and its query then ends at once with no reply; the
  client re-sends the same goal until ``timeout``, and the server answers a re-sent goal
  (same ``goal_id``, same goal) as accepted, so a retry never starts a goal twice.
* ``.../cancel`` — query with :class:`ActionCancel`, answered with :class:`ActionResponse`.
* ``.../feedback`` and ``.../result`` — publications (``event`` QoS) of
  :class:`ActionFeedback` and :class:`ActionResult`, filtered by ``goal_id`` on the client.
* ``.../status`` — a queryable that answers the stored :class:`ActionResult` of a
  finished goal (``?goal_id=...``): the client polls it while waiting, so a result
  published during a router restart is not lost.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal

import zenoh
from quadmanip.common import keys
from quadmanip.common import messages as msgs
from quadmanip.common.bus import TypedPublisher, TypedSubscriber, log
from quadmanip.common.schema import Message, MessageError, decode, encode

if TYPE_CHECKING:
    from quadmanip.common.bus import Bus

__all__ = [
    "ActionCanceled",
    "ActionClient",
    "ActionFailed",
    "ActionServer",
    "ClientGoalHandle",
    "GoalHandle",
]


class ActionFailed(Exception):
    """Raise from an action's execute function to end the goal as ``failed``; ``result``
    (optional) travels in the ActionResult, e.g. where the robot stopped and why."""

    def __init__(self, reason: str = "", result: Message | None = None) -> None:
        super().__init__(reason)
        self.result = result


class ActionCanceled(Exception):
    """Raise from an action's execute function to end the goal as ``canceled`` (with an
    optional ``result`` message, as :class:`ActionFailed`)."""

    def __init__(self, reason: str = "", result: Message | None = None) -> None:
        super().__init__(reason)
        self.result = result


class GoalHandle:
    """The server side of one accepted goal, handed to the execute function."""

    def __init__(self, server: ActionServer, goal_id: str, goal: Message) -> None:
        self.goal_id = goal_id
        self.goal = goal
        self._server = server
        self.cancel_event = threading.Event()

    @property
    def cancel_requested(self) -> bool:
        return self.cancel_event.is_set()

    def check_cancel(self) -> None:
        """Raise :class:`ActionCanceled` if a cancel was requested (call in loops)."""
        if self.cancel_event.is_set():
            raise ActionCanceled("canceled on request")

    def feedback(self, progress: float, text: str = "") -> None:
        """Publish an :class:`ActionFeedback` (progress in [0, 1])."""
        self._server._publish_feedback(self.goal_id, progress, text)


class ActionServer:
    """Serves one action: goal query → accept/reject → execute thread → feedback → result.

    ``execute(handle)`` runs in its own thread per goal and returns the result message (or
    None) for ``succeeded``; it raises :class:`ActionFailed` (reason) for ``failed`` and
    :class:`ActionCanceled` for ``canceled`` (poll ``handle.cancel_requested`` or call
    ``handle.check_cancel()``); any other exception ends the goal ``failed``.
    ``accept(goal)`` may reject a goal up front with a reason. ``policy`` for a goal that
    arrives while another runs: ``reject`` ("busy"), ``preempt`` (cancel the running goal),
    or ``parallel``.
    """

    RESULTS_KEPT = 64

    def __init__(
        self,
        bus: Bus,
        service: str,
        name: str,
        goal_type: type[Message],
        execute: Callable[[GoalHandle], Message | None],
        accept: Callable[[Message], tuple[bool, str]] | None = None,
        policy: Literal["reject", "preempt", "parallel"] = "reject",
    ) -> None:
        if policy not in ("reject", "preempt", "parallel"):
            raise ValueError(f"unknown policy {policy!r}")
        self.base = keys.action_key(bus.robot, service, name)
        self.goal_type = goal_type
        self._bus = bus
        self._execute = execute
        self._accept = accept
        self._policy = policy
        self._lock = threading.Lock()
        self._active: dict[str, GoalHandle] = {}
        self._threads: dict[str, threading.Thread] = {}
        self._results: OrderedDict[str, Any] = OrderedDict()
        self._goals: OrderedDict[str, Message] = OrderedDict()  # accepted ids: re-sends
        self._stopping = False
        self._feedback_pub = TypedPublisher(
            bus, f"{self.base}/feedback", msgs.ActionFeedback, "event"
        )
        self._result_pub = TypedPublisher(bus, f"{self.base}/result", msgs.ActionResult, "event")
        s = bus.session
        self._queryables = [
            s.declare_queryable(f"{self.base}/goal", self._on_goal),
            s.declare_queryable(f"{self.base}/cancel", self._on_cancel),
            s.declare_queryable(f"{self.base}/status", self._on_status),
        ]

    def _reply(self, query: zenoh.Query, msg: Message) -> None:
        try:
            query.reply(query.key_expr, encode(msg))
        except Exception as exc:  # noqa: BLE001
            log.warning("action reply failed", key=str(query.key_expr), error=repr(exc))

    def _respond(self, query: zenoh.Query, goal_id: str, accepted: bool, reason: str) -> None:
        resp = msgs.ActionResponse(
            stamp=self._bus.clock(), goal_id=goal_id, accepted=accepted, reason=reason
        )
        self._reply(query, resp)

    def _resent(self, gid: str, goal: Message) -> tuple[bool, str] | None:
        """The answer to a goal id already accepted (call under ``_lock``): accepted again
        for the same goal (a client's re-send), refused for another; None if new."""
        if gid not in self._goals:
            return None
        return (True, "") if self._goals[gid] == goal else (False, "duplicate goal_id")

    def _on_goal(self, query: zenoh.Query) -> None:
        with query:
            payload = query.payload
            try:
                goal_msg = decode(payload.to_bytes() if payload else b"", expected=msgs.ActionGoal)
            except MessageError as exc:
                self._bus.stats.add(f"{self.base}/goal", "decode_errors", error=str(exc))
                log.throttled(
                    f"decode:{self.base}/goal",
                    1.0,
                    logging.WARNING,
                    "malformed action goal",
                    error=str(exc),
                )
                self._respond(query, "", False, f"malformed goal: {exc}")
                return
            gid = goal_msg.goal_id
            with self._lock:
                resent = self._resent(gid, goal_msg.goal)
            if resent is not None:  # answered before the accept check: it ran already
                self._respond(query, gid, *resent)
                return
            if not isinstance(goal_msg.goal, self.goal_type):
                self._respond(
                    query,
                    gid,
                    False,
                    f"wrong goal type {type(goal_msg.goal).__name__}, "
                    f"expected {self.goal_type.__name__}",
                )
                return
            if self._accept is not None:
                try:
                    ok, reason = self._accept(goal_msg.goal)
                except Exception as exc:  # noqa: BLE001
                    ok, reason = False, f"accept check raised {exc!r}"
                if not ok:
                    self._respond(query, gid, False, reason or "rejected")
                    return
            with self._lock:
                if self._stopping:
                    self._respond(query, gid, False, "server shutting down")
                    return
                resent = self._resent(gid, goal_msg.goal)  # raced past the check above
                if resent is not None:
                    self._respond(query, gid, *resent)
                    return
                if self._active and self._policy == "reject":
                    busy = ",".join(self._active)
                    self._respond(query, gid, False, f"busy with goal {busy}")
                    return
                if self._policy == "preempt":
                    for other in self._active.values():
                        other.cancel_event.set()
                handle = GoalHandle(self, gid, goal_msg.goal)
                self._active[gid] = handle
                self._goals[gid] = goal_msg.goal
                while len(self._goals) > self.RESULTS_KEPT:
                    self._goals.popitem(last=False)
                t = threading.Thread(
                    target=self._run, args=(handle,), name=f"action:{gid}", daemon=True
                )
                self._threads[gid] = t
            self._respond(query, gid, True, "")
            log.info("goal accepted", action=self.base, goal_id=gid)
            t.start()

    def _run(self, handle: GoalHandle) -> None:
        status, reason, result = "succeeded", "", None
        try:
            result = self._execute(handle)
        except ActionCanceled as exc:
            status, reason, result = "canceled", str(exc) or "canceled", exc.result
        except ActionFailed as exc:
            status, reason, result = "failed", str(exc) or "failed", exc.result
        except Exception as exc:  # noqa: BLE001
            status, reason = "failed", f"{type(exc).__name__}: {exc}"
            log.error(
                "action execute raised",
                action=self.base,
                goal_id=handle.goal_id,
                error=repr(exc),
                exc_info=True,
            )
        msg = msgs.ActionResult(
            stamp=self._bus.clock(),
            goal_id=handle.goal_id,
            status=status,
            reason=reason,
            result=result,
        )
        with self._lock:
            self._active.pop(handle.goal_id, None)
            self._threads.pop(handle.goal_id, None)
            self._results[handle.goal_id] = msg
            while len(self._results) > self.RESULTS_KEPT:
                self._results.popitem(last=False)
        log.info(
            "goal finished", action=self.base, goal_id=handle.goal_id, status=status, reason=reason
        )
        try:
            self._result_pub.publish(msg)
        except Exception as exc:  # noqa: BLE001 - a closing session; result stays queryable
            log.warning("publishing action result failed", error=repr(exc))

    def _publish_feedback(self, goal_id: str, progress: float, text: str) -> None:
        msg = msgs.ActionFeedback(
            stamp=self._bus.clock(), goal_id=goal_id, progress=float(progress), text=text
        )
        try:
            self._feedback_pub.publish(msg)
        except Exception as exc:  # noqa: BLE001
            log.throttled(
                f"feedback:{self.base}",
                1.0,
                logging.WARNING,
                "publishing feedback failed",
                error=repr(exc),
            )

    def _on_cancel(self, query: zenoh.Query) -> None:
        with query:
            payload = query.payload
            try:
                cancel = decode(payload.to_bytes() if payload else b"", expected=msgs.ActionCancel)
            except MessageError as exc:
                self._respond(query, "", False, f"malformed cancel: {exc}")
                return
            with self._lock:
                handle = self._active.get(cancel.goal_id)
            if handle is None:
                self._respond(query, cancel.goal_id, False, "no such active goal")
                return
            handle.cancel_event.set()
            self._respond(query, cancel.goal_id, True, "cancel requested")

    def _on_status(self, query: zenoh.Query) -> None:
        with query:
            gid = query.parameters.get("goal_id") or ""
            with self._lock:
                result = self._results.get(gid)
            if result is not None:
                self._reply(query, result)

    def stop(self, timeout: float = 0.5) -> None:
        """Cancel running goals and wait briefly for them (called by ``Bus.close``)."""
        with self._lock:
            self._stopping = True
            handles = list(self._active.values())
            threads = list(self._threads.values())
        for h in handles:
            h.cancel_event.set()
        deadline = time.monotonic() + timeout
        for t in threads:
            t.join(max(0.0, deadline - time.monotonic()))

    def undeclare(self) -> None:
        for q in self._queryables:
            try:
                q.undeclare()
            except Exception:  # noqa: BLE001
                pass
        self._feedback_pub.undeclare()
        self._result_pub.undeclare()


class ClientGoalHandle:
    """The client side of one sent goal: acceptance, feedback, result, cancel."""

    def __init__(
        self,
        client: ActionClient,
        goal_id: str,
        feedback_cb: Callable[[Any], Any] | None,
    ) -> None:
        self.goal_id = goal_id
        self.accepted = False
        self.reason = ""
        self.feedback: list[Any] = []
        self._client = client
        self._feedback_cb = feedback_cb
        self._done = threading.Event()
        self._result: Any = None

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def _set_result(self, result: Any) -> None:
        if not self._done.is_set():
            self._result = result
            self._done.set()

    def result(self, timeout: float | None = None, poll_s: float = 2.0) -> Any:
        """Wait for the :class:`ActionResult` (None on timeout or if not accepted).

        While waiting it polls the server's status queryable every ``poll_s`` so that a
        result lost in transit (router restart) is still recovered.
        """
        if not self.accepted:
            return None
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                return self._result if self._done.is_set() else None
            wait = poll_s if remaining is None else min(poll_s, remaining)
            if self._done.wait(wait):
                return self._result
            polled = self._client._poll_status(self.goal_id)
            if polled is not None:
                self._set_result(polled)
                return polled

    def cancel(self, timeout: float = 1.0) -> bool:
        """Ask the server to cancel; True if it acknowledged an active goal."""
        return self._client._cancel(self.goal_id, timeout)


class ActionClient:
    """Sends goals to ``<service>/action/<name>``; see the module doc for the protocol."""

    def __init__(self, bus: Bus, service: str, name: str, goal_type: type[Message]) -> None:
        self.base = keys.action_key(bus.robot, service, name)
        self.goal_type = goal_type
        self._bus = bus
        self._lock = threading.Lock()
        self._handles: dict[str, ClientGoalHandle] = {}
        self._subs = [
            TypedSubscriber(bus, f"{self.base}/feedback", msgs.ActionFeedback, self._on_feedback),
            TypedSubscriber(bus, f"{self.base}/result", msgs.ActionResult, self._on_result),
        ]
        self._counter = itertools.count()

    def _on_feedback(self, msg: Any) -> None:
        with self._lock:
            h = self._handles.get(msg.goal_id)
        if h is None:
            return
        h.feedback.append(msg)
        if h._feedback_cb is not None:
            h._feedback_cb(msg)

    def _on_result(self, msg: Any) -> None:
        with self._lock:
            h = self._handles.pop(msg.goal_id, None)
        if h is not None:
            h._set_result(msg)

    def _query(self, key: str, payload: bytes | None, timeout: float, params: str = "") -> Any:
        selector = f"{key}?{params}" if params else key
        replies = self._bus.session.get(selector, payload=payload, timeout=timeout)
        for reply in replies:
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
        return None

    def send_goal(
        self,
        goal: Message,
        *,
        timeout: float = 2.0,
        feedback_cb: Callable[[Any], Any] | None = None,
        goal_id: str | None = None,
    ) -> ClientGoalHandle:
        """Send ``goal``; returns with ``handle.accepted`` / ``handle.reason`` set as soon as
        a server answers, or after ``timeout`` s ("no action server answered"). A goal of
        another type than the key table's row is refused with ``TypeError``."""
        if not isinstance(goal, self.goal_type):
            raise TypeError(
                f"action {self.base} takes {self.goal_type.__name__}, got {type(goal).__name__}"
            )
        gid = goal_id or f"{uuid.uuid4().hex[:12]}-{next(self._counter)}"
        handle = ClientGoalHandle(self, gid, feedback_cb)
        with self._lock:
            self._handles[gid] = handle  # before sending: feedback may beat the reply
        envelope = msgs.ActionGoal(
            stamp=self._bus.clock(), goal_id=gid, action=self.base, goal=goal
        )
        data, deadline = None, time.monotonic() + timeout
        while data is None and (left := deadline - time.monotonic()) > 0:
            data = self._query(f"{self.base}/goal", encode(envelope), left)
            if data is None:  # no server known to this session yet: ask again
                time.sleep(min(0.05, max(0.0, deadline - time.monotonic())))
        if data is None:
            handle.reason = "no action server answered"
        else:
            try:
                resp = decode(data, expected=msgs.ActionResponse)
                handle.accepted, handle.reason = bool(resp.accepted), resp.reason
            except MessageError as exc:
                handle.reason = f"malformed response: {exc}"
        if not handle.accepted:
            with self._lock:
                self._handles.pop(gid, None)
        return handle

    def _cancel(self, goal_id: str, timeout: float) -> bool:
        data = self._query(
            f"{self.base}/cancel",
            encode(msgs.ActionCancel(stamp=self._bus.clock(), goal_id=goal_id)),
            timeout,
        )
        if data is None:
            return False
        try:
            return bool(decode(data, expected=msgs.ActionResponse).accepted)
        except MessageError:
            return False

    def _poll_status(self, goal_id: str) -> Any:
        try:
            data = self._query(f"{self.base}/status", None, 1.0, params=f"goal_id={goal_id}")
        except Exception:  # noqa: BLE001 - session trouble: keep waiting for the publication
            return None
        if data is None:
            return None
        try:
            return decode(data, expected=msgs.ActionResult)
        except MessageError:
            return None

    def undeclare(self) -> None:
        for s in self._subs:
            s.undeclare()
