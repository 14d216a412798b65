"""The object catalogue (``configs/objects.toml``) and how each object becomes MuJoCo geoms.

The 18 objects of the paper's Section 7.1 are YCB objects; the simulator cannot use their
scanned meshes (MuJoCo collides the convex hull of a mesh, which would close a bowl's
opening), so each object is composed of convex primitives: a box, a cylinder, a sphere, a
recipe of parts, or a *vessel* (bowl, mug, cup) made of a ring of wall slabs plus a bottom
disk, so its rim and opening are real. A part may be a *dish* (a spoon's bowl): a thin
elliptical shell of a floor plate and a ring of leaning wall slabs. Sizes and masses are the
YCB numbers; the mass is split over the parts by volume times a relative density.

Each object (and optionally each part) is made of a catalogue *material*; the robot's
silicone finger pads touch it with that material's pad friction (``[pad_friction]``),
through explicit MuJoCo contact pairs (:class:`PadContacts`): the friction of a pad
contact is a property of the pair, not of either surface, and the object keeps its own
friction against everything else (floor, tables, containers, other objects).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np
from quadmanip.common.object_catalogue import (
    Catalogue,
    Contact,
    ObjectSpec,
    PadFriction,
    Part,
    PartType,
    Vessel,
    load_catalogue,
)
from quadmanip.common.rotations import (
    quat_from_axis_angle,
    quat_from_euler_xyz,
    quat_mul,
    quat_to_mat,
)

__all__ = [
    "Catalogue",
    "Contact",
    "ObjectSpec",
    "PadContacts",
    "PadFriction",
    "Part",
    "Vessel",
    "add_object",
    "load_catalogue",
    "object_parts",
    "pad_contacts",
]

# Collision bits (MuJoCo: two geoms collide if contype1 & conaffinity2 or contype2 &
# conaffinity1). Ordinary geoms (house, robot) keep the default 1/1. The robot's finger pads
# are contype 1 / conaffinity 2 (configs/robot/quadmanip_dog.xml): they touch every ordinary
# geom. Objects paired with the pads are contype 5 / conaffinity 4: they touch ordinary
# geoms (bit 1 of their contype) and each other (bit 4), but not the pads dynamically:
# those contacts come from the explicit pairs, with the pad-vs-material friction.
OBJECT_CONTYPE = 5
OBJECT_CONAFFINITY = 4

_GEOM_TYPE = {
    "box": mujoco.mjtGeom.mjGEOM_BOX,
    "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
    "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE,
    "ellipsoid": mujoco.mjtGeom.mjGEOM_ELLIPSOID,
}


# ----------------------------------------------------------------------------- geometry


@dataclass(frozen=True)
class _Geom:
    type: PartType
    size: tuple[float, ...]
    pos: np.ndarray
    quat: np.ndarray
    weight: float
    rgba: tuple[float, float, float, float] | None
    material: str | None = None  # None: the object's


def _volume(kind: str, size: tuple[float, ...]) -> float:
    if kind == "box":
        return 8.0 * size[0] * size[1] * size[2]
    if kind == "cylinder":
        return math.pi * size[0] ** 2 * 2.0 * size[1]
    if kind == "sphere":
        return 4.0 / 3.0 * math.pi * size[0] ** 3
    if kind == "capsule":
        return math.pi * size[0] ** 2 * 2.0 * size[1] + 4.0 / 3.0 * math.pi * size[0] ** 3
    if kind == "ellipsoid":
        return 4.0 / 3.0 * math.pi * size[0] * size[1] * size[2]
    raise ValueError(kind)


def _vessel_geoms(obj: ObjectSpec) -> list[_Geom]:
    """Ring of wall slabs + bottom disk (+ C-shaped handle): a container with a real opening.

    The slabs' outer faces form a regular N-gon whose inradius is the rim radius, so the
    bounding box equals the catalogue size exactly; the slabs start inside the bottom disk,
    so the vessel stands on its disk alone. A flared wall (bowl, cup) leans out by
    the angle that joins the foot diameter to the rim diameter.
    """
    v = obj.vessel
    assert v is not None
    sx, diameter, height = obj.size
    reach = sx - diameter  # handle reach beyond the body (0 without a handle)
    axis_x = -0.5 * reach
    t, n = v.wall, v.segments
    r_top, r_foot = 0.5 * diameter, 0.5 * v.bottom_diameter
    z_lo, z_hi = -0.5 * height, 0.5 * height
    alpha = math.atan2(r_top - r_foot, height)
    for _ in range(8):  # fixed point: the corners depend on the lean angle
        s, c = math.sin(alpha), math.cos(alpha)
        r_b, z_b = r_top - 0.5 * t * c, z_hi - 0.5 * t * s
        # The wall's lowest corner sits inside the bottom disk, not on the support: only the
        # disk touches the table (3-4 contacts instead of two per slab).
        r_a, z_a = r_foot - 0.5 * t * c, z_lo + 0.5 * v.bottom + 0.5 * t * s
        alpha = math.atan2(r_b - r_a, z_b - z_a)
    length = math.hypot(r_b - r_a, z_b - z_a)
    r_mid, z_mid = 0.5 * (r_a + r_b), 0.5 * (z_a + z_b)
    half_w = r_top * math.tan(math.pi / n)
    q_lean = quat_from_axis_angle((0.0, 1.0, 0.0), alpha)
    geoms: list[_Geom] = []
    for k in range(n):
        th = 2.0 * math.pi * k / n
        pos = np.array([axis_x + r_mid * math.cos(th), r_mid * math.sin(th), z_mid])
        quat = quat_mul(quat_from_axis_angle((0.0, 0.0, 1.0), th), q_lean)
        geoms.append(_Geom("box", (0.5 * t, half_w, 0.5 * length), pos, quat, 1.0, None))
    disk_r = r_a
    geoms.append(
        _Geom(
            "cylinder",
            (disk_r, 0.5 * v.bottom),
            np.array([axis_x, 0.0, z_lo + 0.5 * v.bottom]),
            np.array([1.0, 0.0, 0.0, 0.0]),
            1.0,
            None,
        )
    )
    if v.handle and reach > 0:
        bar, hw = 0.008, 0.006  # handle bar thickness and half-width (y)
        x_wall = axis_x + r_top - t  # arms start inside the wall for a solid joint
        x_out = 0.5 * sx
        z_top, z_bot = z_hi - 0.012, z_lo + 0.015
        arm_half = 0.5 * (x_out - x_wall)
        arm_x = 0.5 * (x_out + x_wall)
        ident = np.array([1.0, 0.0, 0.0, 0.0])
        for z in (z_top - 0.5 * bar, z_bot + 0.5 * bar):
            geoms.append(
                _Geom("box", (arm_half, hw, 0.5 * bar), np.array([arm_x, 0, z]), ident, 1.0, None)
            )
        geoms.append(
            _Geom(
                "box",
                (0.5 * bar, hw, 0.5 * (z_top - z_bot)),
                np.array([x_out - 0.5 * bar, 0.0, 0.5 * (z_top + z_bot)]),
                ident,
                1.0,
                None,
            )
        )
    return geoms


def _dish_geoms(p: Part) -> list[_Geom]:
    """A dish part as boxes: a floor plate and ``segments`` leaning wall slabs.

    The slabs' outer faces start at the polygon of tangents to the rim ellipse (the affine
    image of a regular polygon around the unit circle, with faces at 0 and 90 degrees, so
    the rim reaches exactly the half-axes) and lean inward by ``inset`` down to the floor
    plate, whose half-sizes are the rim's half-axes less the inset. Each slab's lowest
    outer corner lies in the floor plate's mid-plane and its highest corner at the dish's
    top, so the part spans exactly ``size[2]``. Every piece is a box: box-plane and box-box
    collisions are analytic, robust for thin plates.
    """
    assert p.thickness is not None and p.inset is not None and p.segments is not None
    a, b, height = p.size
    t, inset, n = p.thickness, p.inset, p.segments
    z_lo, z_hi = -0.5 * height, 0.5 * height
    rot = quat_from_euler_xyz(p.euler, degrees=True)
    rmat = quat_to_mat(rot)
    centre = np.asarray(p.pos, float)

    def piece(size: tuple[float, ...], pos: np.ndarray, quat: np.ndarray) -> _Geom:
        return _Geom(
            "box", size, centre + rmat @ pos, quat_mul(rot, quat), p.weight, p.rgba, p.material
        )

    geoms = [piece((a - inset, b - inset, 0.5 * t), np.array([0.0, 0.0, z_lo + 0.5 * t]), _IDENT)]
    half_tan = math.tan(math.pi / n)
    alpha = math.atan2(inset, height)
    for _ in range(8):  # fixed point: the corners depend on the lean angle
        sa = math.sin(alpha)
        z_b = z_hi - 0.5 * t * sa  # mid-surface at the top and at the bottom
        z_a = z_lo + 0.5 * t + 0.5 * t * sa
        alpha = math.atan2(inset, z_b - z_a)
    length = math.hypot(inset, z_b - z_a)
    z_mid = 0.5 * (z_a + z_b)
    q_lean = quat_from_axis_angle((0.0, 1.0, 0.0), alpha)
    for k in range(n):
        th = 2.0 * math.pi * k / n
        c, s = math.cos(th), math.sin(th)
        normal = np.array([c / a, s / b])
        d_top = 1.0 / float(np.linalg.norm(normal))  # the rim tangent's distance from centre
        normal *= d_top  # unit outward normal of the tangent at (a c, b s)
        tangent_pt = np.array([a * c, b * s])  # the middle of that polygon edge
        half_w = half_tan * math.hypot(a * s, b * c)  # half the edge's length
        # slab centre: from the tangent point, in along the normal to the mid-surface's
        # middle (outer face at the tangent at the top, ``inset`` further in at the bottom)
        r_shift = 0.5 * t * math.cos(alpha) + 0.5 * inset
        xy = tangent_pt - r_shift * normal
        phi = math.atan2(normal[1], normal[0])
        quat = quat_mul(quat_from_axis_angle((0.0, 0.0, 1.0), phi), q_lean)
        geoms.append(piece((0.5 * t, half_w, 0.5 * length), np.array([*xy, z_mid]), quat))
    return geoms


_IDENT = np.array([1.0, 0.0, 0.0, 0.0])


def object_parts(obj: ObjectSpec) -> list[_Geom]:
    """The convex pieces of an object in its body frame (origin = bounding-box centre)."""
    ident = _IDENT
    sx, sy, sz = obj.size
    if obj.shape == "box":
        return [_Geom("box", (sx / 2, sy / 2, sz / 2), np.zeros(3), ident, 1.0, None)]
    if obj.shape == "cylinder":
        return [_Geom("cylinder", (sx / 2, sz / 2), np.zeros(3), ident, 1.0, None)]
    if obj.shape == "sphere":
        return [_Geom("sphere", (sx / 2,), np.zeros(3), ident, 1.0, None)]
    if obj.shape == "vessel":
        return _vessel_geoms(obj)
    out: list[_Geom] = []
    for p in obj.parts:
        if p.type == "dish":
            out += _dish_geoms(p)
            continue
        out.append(
            _Geom(
                p.type,
                p.size,
                np.asarray(p.pos, float),
                quat_from_euler_xyz(p.euler, degrees=True),
                p.weight,
                p.rgba,
                p.material,
            )
        )
    return out


@dataclass(frozen=True)
class PadContacts:
    """The robot's finger pads in an MjSpec, for pairing them with objects.

    A pad touching an object gets the friction of the pad-vs-material pair from the
    catalogue's ``pad_friction`` table; the contact's softness (solref, solimp), margin and
    gap are the pad's own, from the robot description, and its condim the larger of the
    pad's and the object's (MuJoCo's rule for a dynamic contact). Build it with
    :func:`pad_contacts`.
    """

    spec: mujoco.MjSpec
    pads: tuple[str, ...]
    condim: int
    solref: tuple[float, float]
    solimp: tuple[float, ...]
    margin: float
    gap: float
    friction: dict[str, PadFriction]


def pad_contacts(spec: mujoco.MjSpec, catalogue: Catalogue) -> PadContacts | None:
    """The finger pads of the robot in ``spec`` (None when it holds no robot)."""
    from quadmanip.common.robot_description import FINGER_PAD_GEOMS

    geoms = [spec.geom(name) for name in FINGER_PAD_GEOMS]
    if any(g is None for g in geoms):
        return None
    for g in geoms:
        # the pads must not touch paired objects dynamically (see OBJECT_CONTYPE)
        if g.contype & OBJECT_CONAFFINITY or g.conaffinity & OBJECT_CONTYPE:
            raise ValueError(f"pad {g.name!r}: contype/conaffinity overlap the objects' bits")
    ref = geoms[0]
    return PadContacts(
        spec=spec,
        pads=FINGER_PAD_GEOMS,
        condim=int(ref.condim),
        solref=(float(ref.solref[0]), float(ref.solref[1])),
        solimp=tuple(float(v) for v in ref.solimp),
        margin=float(ref.margin),
        gap=float(ref.gap),
        friction=catalogue.pad_friction,
    )


def add_object(
    parent: mujoco.MjsBody,
    name: str,
    obj: ObjectSpec,
    pos: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0),
    quat: tuple[float, float, float, float] | np.ndarray = (1.0, 0.0, 0.0, 0.0),
    contact: Contact | None = None,
    pads: PadContacts | None = None,
) -> mujoco.MjsBody:
    """Add ``obj/<name>`` (a free body made of the object's convex parts) under ``parent``.

    Every part gets mass = total mass x (weight x volume) / sum(weight x volume), so the body
    weighs exactly the catalogue mass; MuJoCo derives the inertia from the shapes. With
    ``pads`` (the robot's finger pads, :func:`pad_contacts`) every geom gets one explicit
    contact pair per pad with its material's pad friction, and collision bits that keep
    the pads from also touching it dynamically. Without, the pads touch it with the pad's
    own (generic) friction.
    """
    contact = contact or Contact()
    body = parent.add_body(name=f"obj/{name}", pos=list(pos), quat=list(quat))
    body.add_freejoint(name=f"obj/{name}/free")
    geoms = object_parts(obj)
    weighted = [g.weight * _volume(g.type, g.size) for g in geoms]
    total = sum(weighted)
    for i, (g, w) in enumerate(zip(geoms, weighted, strict=True)):
        geom = body.add_geom(
            name=f"obj/{name}/g{i}",
            type=_GEOM_TYPE[g.type],
            size=list(g.size) + [0.0] * (3 - len(g.size)),
            pos=list(g.pos),
            quat=list(g.quat),
            mass=obj.mass * w / total,
            rgba=list(g.rgba or obj.rgba),
            friction=list(obj.friction),
            condim=obj.condim,
            solref=list(contact.solref),
            solmix=contact.solmix,
            group=1,  # world geoms use groups 0/1; the robot keeps 2 (visual) and 3
        )
        if pads is None:
            continue
        geom.contype, geom.conaffinity = OBJECT_CONTYPE, OBJECT_CONAFFINITY
        f = pads.friction[g.material or obj.material]
        for pad in pads.pads:
            pads.spec.add_pair(
                name=f"{pad}/obj/{name}/g{i}",
                geomname1=pad,
                geomname2=geom.name,
                condim=max(pads.condim, obj.condim),
                friction=[f.sliding, f.sliding, f.torsional, f.rolling, f.rolling],
                solref=list(pads.solref),
                solimp=list(pads.solimp),
                margin=pads.margin,
                gap=pads.gap,
            )
    return body
