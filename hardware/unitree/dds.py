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
    ChannelSubscriber,
)

__all__ = ["init_dds", "publisher", "subscriber"]

_initialised: tuple[int, str] | None = None


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


def subscriber(topic: str, msg_type: type, handler: Callable[[Any], None]) -> ChannelSubscriber:
    """A subscriber calling ``handler(sample)`` on the DDS listener thread."""
    sub = ChannelSubscriber(topic, msg_type)
    sub.Init(handler, 0)
    return sub
