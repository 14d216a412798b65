"""Per-object point clouds (paper Section 4.1): a detection box cut from a depth image,
lifted to 3-D with the intrinsic matrix K and the camera pose.

A pixel (u, v) with depth d (metres along the optical axis, the RGB-D convention) lifts to
the optical-frame point ``p_c = d K^-1 [u, v, 1]^T`` (OpenCV pinhole model: x right, y
down, z forward; pixel centres at integer coordinates), and to the base frame with the
camera pose carried by the frame (``RgbdImage.position`` / ``.orientation``, base_T_camera):
``p_b = R_bc p_c + t_bc``. Depth 0 means "no return" and is skipped. Everything is
vectorised: a 100 x 100 box lifts in well under a millisecond.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from quadmanip.common.rotations import quat_to_mat

__all__ = ["Box", "BoxCloud", "clip_box", "lift_box", "lift_pixels", "to_odom"]

Box = tuple[int, int, int, int]
"""A pixel box ``(u0, v0, u1, v1)``: columns u0..u1-1, rows v0..v1-1 (end exclusive)."""


@dataclass(frozen=True)
class BoxCloud:
    """The 3-D points (base frame) of one box cut and where they came from."""

    points: np.ndarray  # (N, 3) float64, base frame
    rows: np.ndarray  # (N,) int, image row of each point
    cols: np.ndarray  # (N,) int, image column of each point
    camera_position: np.ndarray  # (3,) optical centre in the base frame
    box: Box  # the box after clipping to the image
    truncated: tuple[bool, bool, bool, bool]  # box touches the left, top, right, bottom border

    def __len__(self) -> int:
        return int(self.points.shape[0])


def clip_box(box: Sequence[float], shape: tuple[int, int]) -> Box:
    """``box`` rounded outwards to whole pixels and clipped to an image of ``shape`` (H, W)."""
    h, w = shape
    u0, v0, u1, v1 = (float(b) for b in box)
    return (
        int(np.clip(np.floor(u0), 0, w)),
        int(np.clip(np.floor(v0), 0, h)),
        int(np.clip(np.ceil(u1), 0, w)),
        int(np.clip(np.ceil(v1), 0, h)),
    )


def lift_pixels(
    depth: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    K: np.ndarray,
    position: np.ndarray,
    orientation: np.ndarray,
) -> np.ndarray:
    """Points (N, 3) in the frame the camera pose is given in, for pixels (rows, cols) of
    ``depth`` (all assumed valid: depth > 0)."""
    K = np.asarray(K, dtype=float)
    d = depth[rows, cols].astype(float)
    # K^-1 [u v 1]^T for a pinhole K without skew, written out (cheaper than a solve)
    fx, fy, cx, cy, s = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    y = (rows - cy) / fy
    x = (cols - cx - s * y) / fx
    pc = np.stack([x * d, y * d, d], axis=1)
    r = quat_to_mat(orientation)
    return pc @ r.T + np.asarray(position, dtype=float)


def lift_box(
    depth: np.ndarray,
    box: Sequence[float],
    K: np.ndarray,
    position: np.ndarray,
    orientation: np.ndarray,
    stride: int = 1,
    max_depth: float = np.inf,
) -> BoxCloud:
    """Section 4.1: the depth pixels inside ``box`` as base-frame points.

    ``stride`` keeps every stride-th row and column (a cheaper, sparser cloud);
    ``max_depth`` (m) drops returns beyond it. Pixels without a return (0) are skipped.
    """
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    depth = np.asarray(depth)
    b = clip_box(box, depth.shape)
    u0, v0, u1, v1 = b
    vv, uu = np.mgrid[v0:v1:stride, u0:u1:stride]
    rows, cols = vv.ravel(), uu.ravel()
    d = depth[rows, cols]
    ok = (d > 0) & (d <= max_depth)
    rows, cols = rows[ok], cols[ok]
    pts = lift_pixels(depth, rows, cols, K, position, orientation)
    h, w = depth.shape
    return BoxCloud(
        points=pts,
        rows=rows,
        cols=cols,
        camera_position=np.asarray(position, dtype=float).copy(),
        box=b,
        truncated=(u0 <= 0, v0 <= 0, u1 >= w, v1 >= h),
    )


def to_odom(
    points: np.ndarray, base_position: np.ndarray, base_orientation: np.ndarray
) -> np.ndarray:
    """Base-frame points (N, 3) to the odom frame, given the base pose in odom (position,
    quaternion [w, x, y, z])."""
    r = quat_to_mat(base_orientation)
    return np.asarray(points, dtype=float) @ r.T + np.asarray(base_position, dtype=float)
