"""DDS set-up for the Unitree SDK2: one domain per process, bound to one network interface.

A real Go2 talks on domain 0 over the Ethernet interface wired to it (e.g. ``eth0``,
192.168.123.x); the simulated robot uses the loopback interface ``lo`` and its own domain
so that a test never reaches a robot on the network. The SDK's channel factory is a
process-wide singleton: :func:`init_dds` refuses a second, different initialisation.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from unitree_sdk2py.core.channel import (
    ChannelFactoryInitialize,
    ChannelPublisher,
)

__all__ = ["init_dds", "publisher", "raw_subscriber"]

_initialised: tuple[int, str] | None = None
_participant: Any = None


def init_dds(domain_id: int, interface: str) -> None:
    """Join DDS domain ``domain_id`` on network interface ``interface`` (once per process)."""
    global _initialised
    want = (int(domain_id), str(interface))
    if _initialised is not None:
        if _initialised != want:
            raise RuntimeError(f"DDS already initialised as {_initialised}, not {want}")
        return
    if not 0 <= want[0] <= 232:
        raise ValueError(f"DDS domain id must be in 0..232, got {domain_id}")
    ChannelFactoryInitialize(want[0], want[1] or None)
    _initialised = want


def publisher(topic: str, msg_type: type) -> ChannelPublisher:
    """A ready publisher of ``msg_type`` on ``topic``."""
    pub = ChannelPublisher(topic, msg_type)
    pub.Init()
    return pub


class RawSubscriber:
    """A reader that hands each valid sample's wire bytes to ``on_bytes`` (DDS listener
    thread) instead of the SDK's Python deserialiser (wire_format.py says why); the
    topic and type are the SDK's, so it matches the robot's writers as the SDK's own
    subscriber does."""

    def __init__(self, topic: str, msg_type: type, on_bytes: Callable[[bytes], None]) -> None:
        from cyclonedds._clayer import ddspy_take
        from cyclonedds.core import Listener
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        global _participant
        if _initialised is None:
            raise RuntimeError("init_dds() first")
        if _participant is None:
            _participant = DomainParticipant(_initialised[0])
        self._take = ddspy_take
        self._on_bytes = on_bytes
        self._closed = False
        self._topic = Topic(_participant, topic, msg_type)
        self._reader = DataReader(
            _participant, self._topic, listener=Listener(on_data_available=self._on_data)
        )

    def _on_data(self, reader: Any) -> None:
        if self._closed or reader is None:  # closing, or the reader is already deleted
            return
        ret = self._take(reader._ref, 8)
        if isinstance(ret, int):  # a DDS error code
            return
        for data, info in ret:
            if info.valid_data:
                self._on_bytes(data)

    def close(self) -> None:
        """Delete the reader now, in this thread. Only dropping the reference let the
        last one go in the listener's own callback (cyclonedds holds the reader there),
        whose ``dds_delete`` then waited for that callback to end: a deadlock."""
        from cyclonedds.core import Entity

        reader, self._reader = self._reader, None
        if reader is None:
            return
        self._closed = True
        Entity._entities.pop(reader._ref, None)  # the object's own __del__ is a no-op now
        reader._delete(reader._ref)  # waits for a running callback (ctypes frees the GIL)


def raw_subscriber(topic: str, msg_type: type, on_bytes: Callable[[bytes], None]) -> RawSubscriber:
    """A :class:`RawSubscriber` (after :func:`init_dds`)."""
    return RawSubscriber(topic, msg_type, on_bytes)
