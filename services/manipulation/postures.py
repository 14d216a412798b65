"""Named arm postures from configuration (Figs. 5a-c and 12a-b, carry, stow).

Postures are stored in ``configs/manipulation.toml`` either as joints or as a tool target
in the arm_base frame; tool targets are solved once with the analytic IK so that a posture
that became unreachable after a description change fails loudly at load time.
"""

from __future__ import annotations

import numpy as np
from quadmanip.services.manipulation.arm_kinematics import ArmGeometry, ArmTarget, solve_ik
from quadmanip.services.manipulation.config import ManipulationConfig

__all__ = ["REQUIRED_POSTURES", "PostureError", "resolve_postures"]

REQUIRED_POSTURES: tuple[str, ...] = (
    "floor_search",
    "table_search",
    "probe_floor",
    "probe_table",
    "probe_horizontal",
    "probe_tall",
    "carry",
    "stow",
)


class PostureError(ValueError):
    """A configured posture is missing, unreachable or outside the joint limits."""


def resolve_postures(geom: ArmGeometry, cfg: ManipulationConfig) -> dict[str, np.ndarray]:
    """Joint vectors of every configured posture, checked against the joint limits."""
    out: dict[str, np.ndarray] = {}
    lo = np.asarray(geom.q_min)
    hi = np.asarray(geom.q_max)
    for name, spec in cfg.postures.items():
        if len(spec.q) == 4:
            q = np.asarray(spec.q, dtype=float)
            if np.any(q < lo) or np.any(q > hi):
                raise PostureError(f"posture {name!r} outside the joint limits: {q}")
        else:
            x, z, pitch, roll = spec.tcp
            sol = solve_ik(
                geom, ArmTarget(x, z, pitch, roll), q_ref=cfg.motion.elbow_ref, roll_symmetric=False
            )
            if not sol.ok:
                raise PostureError(f"posture {name!r} unreachable: {sol.reason}: {sol.detail}")
            q = np.asarray(sol.q)
        out[name] = q
    missing = [n for n in REQUIRED_POSTURES if n not in out]
    if missing:
        raise PostureError(f"configs/manipulation.toml lacks postures: {', '.join(missing)}")
    return out
