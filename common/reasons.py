"""Texts in action results that more than one service reads (transport-free, so the
services' algorithm modules may import it).

A reason is a short code and a human-readable detail ("unreachable: ..."); where the
caller acts on more than the code, the clause it parses is written and read here only.
"""

from __future__ import annotations

import math
import re

__all__ = [
    "narrow_side_text",
    "parse_narrow_side",
    "parse_reach_band",
    "parse_refused_class",
    "reach_band_text",
    "refusal_text",
]


#: How a grasp refused as unreachable names the distances ahead (body x, m) it would be
#: planned from: manipulation appends it to the refusal's reason, the task steps into it.
_REACH_BAND = re.compile(r"reachable (-?\d+\.\d+)-(-?\d+\.\d+) m ahead \(asked (-?\d+\.\d+)\)")


def reach_band_text(lo: float, hi: float, asked: float) -> str:
    """The reason's clause naming the reachable band ``lo``-``hi`` for a grasp ``asked``
    at that distance ahead."""
    return f"reachable {lo:.3f}-{hi:.3f} m ahead (asked {asked:.3f})"


def parse_reach_band(reason: str) -> tuple[float, float, float] | None:
    """(lo, hi, asked) from a reason holding :func:`reach_band_text`'s clause, else None."""
    m = _REACH_BAND.search(reason)
    return None if m is None else (float(m[1]), float(m[2]), float(m[3]))


#: How perception's refusal of a horizontal grasp names where a long box's narrow side
#: faces: the turn of the robot's heading (deg, left positive) that looks along the box's
#: long side. The task stands that way (or the opposite way) and probes again.
_NARROW_SIDE = re.compile(r"narrow side seen turned (-?\d+) deg")


def narrow_side_text(turn: float) -> str:
    """The reason's clause naming the turn ``turn`` (rad) that shows a box's narrow side."""
    return f"narrow side seen turned {round(math.degrees(turn)):d} deg"


def parse_narrow_side(reason: str) -> float | None:
    """The turn (rad) of a reason holding :func:`narrow_side_text`'s clause, else None."""
    m = _NARROW_SIDE.search(reason)
    return None if m is None else math.radians(float(m[1]))


#: How perception's refusal of an estimate names what it saw: "<code>: <class> in
#: <camera> (<detail>)". The task reads the class of a refusal to probe from the side
#: (a "mug" from afar that the close view sees as a coffee can, too tall to take from above).
_REFUSED = re.compile(r"^([a-z ]+): ([a-z_]+) in ([a-z_]+camera)\b")


def refusal_text(code: str, label: str, camera: str, detail: str = "") -> str:
    """A refused estimate's reason: ``code`` (e.g. "probe horizontally"), the class it saw
    and the camera; ``detail`` in brackets after it."""
    return f"{code}: {label} in {camera}" + (f" ({detail})" if detail else "")


def parse_refused_class(reason: str, code: str) -> str | None:
    """The class named by a reason written by :func:`refusal_text` with ``code``, else None."""
    m = _REFUSED.match(reason)
    return m[2] if m is not None and m[1] == code else None
