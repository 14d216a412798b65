"""The house (``configs/house.toml``): rooms, walls, tables, furniture, the drawer cabinet and
the six deposit places of the paper's Figure 21, built into a ``mujoco.MjSpec``.

Geometry is boxes and cylinders only, so collision and rendering stay cheap. Static parts
live in jointless bodies (MuJoCo never collides static against static); each drawer is a
body on a damped, limited prismatic joint with a handle bar the gripper can hook or pinch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import mujoco
import numpy as np
from quadmanip.common.config import load_config
from quadmanip.common.rotations import mat_to_quat, quat_from_yaw

__all__ = [
    "OBSTACLE_RGBA",
    "Block",
    "Cabinet",
    "CameraSpec",
    "Container",
    "DepositRegion",
    "Drawer",
    "FloorArea",
    "HouseConfig",
    "HouseLayout",
    "RobotStart",
    "Room",
    "REACH_EDGES",
    "Surface",
    "add_obstacle",
    "Table",
    "Wall",
    "build_house",
    "camera_quat",
    "load_house",
]


#: Sides of a table a robot may stand at (``Table.reach_edge``; "" for none named).
REACH_EDGES = ("", "south", "north", "west", "east")


@dataclass(frozen=True)
class Room:
    """A room's floor rectangle (inner faces of its walls)."""

    name: str
    min: tuple[float, float]
    max: tuple[float, float]


@dataclass(frozen=True)
class Wall:
    """A wall as a plan rectangle [x0, y0, x1, y1]; doorways are gaps between walls."""

    name: str
    rect: tuple[float, float, float, float]


@dataclass(frozen=True)
class Table:
    """A table: top centre (x, y), top size (x, y), top height; ``spawn`` if objects lie on it,
    ``reach_edge`` ("south", "north", "west", "east") the side a robot stands at to reach
    its top (scenarios lay objects within reach of it; empty: anywhere on the top)."""

    name: str
    room: str
    center: tuple[float, float]
    size: tuple[float, float]
    height: float
    rgba: tuple[float, float, float, float]
    spawn: bool = False
    reach_edge: str = ""

    def __post_init__(self) -> None:
        if self.reach_edge not in REACH_EDGES:
            raise ValueError(
                f"table {self.name!r}: reach_edge {self.reach_edge!r} is not one of "
                f"{', '.join(repr(e) for e in REACH_EDGES)}"
            )


@dataclass(frozen=True)
class Block:
    """A plain box of furniture standing on the floor (sofa, shelf): an obstacle."""

    name: str
    center: tuple[float, float]
    size: tuple[float, float, float]
    rgba: tuple[float, float, float, float]


@dataclass(frozen=True)
class Container:
    """An open-top box that is a deposit place; stands on a table (``on``) or the floor."""

    name: str
    on: str
    center: tuple[float, float]
    size: tuple[float, float, float]
    wall: float
    bottom: float
    rgba: tuple[float, float, float, float]


@dataclass(frozen=True)
class Drawer:
    """One drawer slot in the cabinet frame: lateral centre y, bottom z, outer width/height."""

    name: str
    y: float
    z: float
    width: float
    height: float


@dataclass(frozen=True)
class Cabinet:
    """The drawer cabinet (paper Figure 20): carcass, drawers on prismatic joints, handles."""

    name: str
    center: tuple[float, float]
    yaw: float
    width: float
    depth: float
    height: float
    panel: float
    rgba: tuple[float, float, float, float]
    front_rgba: tuple[float, float, float, float]
    handle_rgba: tuple[float, float, float, float]
    drawer_depth: float
    drawer_mass: float
    travel: float
    damping: float
    frictionloss: float
    handle_length: float
    handle_bar: float
    handle_offset: float
    drawers: tuple[Drawer, ...] = ()


@dataclass(frozen=True)
class FloorArea:
    """A floor rectangle where scenario objects may be placed."""

    name: str
    room: str
    min: tuple[float, float]
    max: tuple[float, float]


@dataclass(frozen=True)
class RobotStart:
    """Where the robot starts: plan position, yaw (deg), footprint kept free of objects, and
    the keyframes to start in, first one the robot description has wins."""

    position: tuple[float, float]
    yaw: float
    footprint: tuple[float, float]
    keyframes: tuple[str, ...] = ("home",)


@dataclass(frozen=True)
class CameraSpec:
    """A fixed snapshot camera looking from ``pos`` at ``target``."""

    name: str
    pos: tuple[float, float, float]
    target: tuple[float, float, float]
    fovy: float = 60.0


@dataclass(frozen=True)
class HouseConfig:
    """The whole house as configured in ``configs/house.toml``."""

    wall_height: float
    table_top_thickness: float
    table_leg: float
    cabinet: Cabinet
    robot_start: RobotStart
    rooms: tuple[Room, ...] = ()
    walls: tuple[Wall, ...] = ()
    tables: tuple[Table, ...] = ()
    blocks: tuple[Block, ...] = ()
    containers: tuple[Container, ...] = ()
    floor_areas: tuple[FloorArea, ...] = ()
    cameras: tuple[CameraSpec, ...] = ()

    def table(self, name: str) -> Table:
        """The table called ``name``."""
        for t in self.tables:
            if t.name == name:
                return t
        raise KeyError(name)

    def room_at(self, x: float, y: float) -> str | None:
        """Name of the room containing the plan point (x, y), or None."""
        for r in self.rooms:
            if r.min[0] <= x <= r.max[0] and r.min[1] <= y <= r.max[1]:
                return r.name
        return None


@lru_cache(maxsize=4)
def load_house(name_or_path: str = "house") -> HouseConfig:
    """Load and validate the house configuration (cached; it is immutable)."""
    return load_config(HouseConfig, name_or_path)


@dataclass(frozen=True)
class DepositRegion:
    """A deposit place's inner volume, for the judge: an axis-aligned box in the frame of
    ``body`` ("world" for fixed ones, so a drawer's region moves with the drawer) from the
    inner bottom up to the rim. ``support_body`` is the body whose geoms hold objects that
    lie in the place (the container, the drawer)."""

    place: str
    name: str
    body: str
    center: tuple[float, float, float]
    half_size: tuple[float, float, float]
    support_body: str

    @property
    def bottom(self) -> float:
        """Height of the inner bottom in the region's body frame."""
        return self.center[2] - self.half_size[2]

    @property
    def rim(self) -> float:
        """Height of the rim in the region's body frame."""
        return self.center[2] + self.half_size[2]

    def contains_local(self, p_local: np.ndarray, top: float | None = None) -> bool:
        """Whether a point given in the region's body frame lies inside the inner volume;
        ``top`` (body frame) replaces the rim as the upper bound."""
        p = np.asarray(p_local, float)
        c, h = self.center, self.half_size
        hi = self.rim if top is None else top
        return bool(
            abs(p[0] - c[0]) <= h[0] and abs(p[1] - c[1]) <= h[1] and self.bottom <= p[2] <= hi
        )


@dataclass(frozen=True)
class Surface:
    """A horizontal rectangle objects may rest on: a floor area or a table top (with the
    table's ``reach_edge``)."""

    name: str
    kind: str  # "floor" | "table"
    room: str
    z: float
    min: tuple[float, float]
    max: tuple[float, float]
    reach_edge: str = ""


@dataclass(frozen=True)
class HouseLayout:
    """What ``build_house`` added that others need by name."""

    regions: tuple[DepositRegion, ...]
    surfaces: tuple[Surface, ...]
    drawer_joints: dict[str, str] = field(default_factory=dict)
    drawer_bodies: dict[str, str] = field(default_factory=dict)
    drawer_handles: dict[str, str] = field(default_factory=dict)
    cameras: tuple[str, ...] = ()


# ----------------------------------------------------------------------------- helpers

_BOX = mujoco.mjtGeom.mjGEOM_BOX
#: Furniture, walls and drawers are stiff (wood): time constant 4 physics steps, so objects
#: dropped into a tray or drawer do not sink into its thin bottom. The floor keeps MuJoCo's
#: default so the legged robot's foot contacts are exactly what locomotion was tuned on.
FURNITURE_SOLREF = (0.004, 1.0)


def camera_quat(pos: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Quaternion of a MuJoCo camera (looks along its -z, y up) at ``pos`` facing ``target``."""
    f = np.asarray(target, float) - np.asarray(pos, float)
    f /= np.linalg.norm(f)
    x = np.cross(f, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-9:
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    z = -f
    y = np.cross(z, x)
    return mat_to_quat(np.column_stack([x, y, z]))


def _box(
    body: mujoco.MjsBody,
    name: str,
    center: tuple[float, float, float] | list[float],
    half: tuple[float, float, float] | list[float],
    rgba: tuple[float, ...] | list[float],
    material: str = "",
    mass: float | None = None,
) -> mujoco.MjsGeom:
    geom = body.add_geom(
        name=name,
        type=_BOX,
        pos=list(center),
        size=list(half),
        rgba=list(rgba),
        group=0,
        solref=list(FURNITURE_SOLREF),
    )
    if material:
        geom.material = material
    if mass is not None:
        geom.mass = mass
    return geom


def _open_box(
    body: mujoco.MjsBody,
    prefix: str,
    size: tuple[float, float, float],
    wall: float,
    bottom: float,
    rgba: tuple[float, ...],
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> None:
    """Bottom plate + four walls of an open box of outer ``size`` whose floor centre is at
    ``origin`` (body frame)."""
    sx, sy, sz = size
    ox, oy, oz = origin
    _box(body, f"{prefix}/bottom", (ox, oy, oz + bottom / 2), (sx / 2, sy / 2, bottom / 2), rgba)
    hz = (sz - bottom) / 2
    zc = oz + bottom + hz
    for sign, tag in ((1, "px"), (-1, "nx")):
        _box(
            body,
            f"{prefix}/wall_{tag}",
            (ox + sign * (sx - wall) / 2, oy, zc),
            (wall / 2, sy / 2, hz),
            rgba,
        )
    for sign, tag in ((1, "py"), (-1, "ny")):
        _box(
            body,
            f"{prefix}/wall_{tag}",
            (ox, oy + sign * (sy - wall) / 2, zc),
            (sx / 2 - wall, wall / 2, hz),
            rgba,
        )


# ----------------------------------------------------------------------------- build


def _add_visuals(spec: mujoco.MjSpec) -> None:
    spec.add_texture(
        name="house/floor_tex",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        width=256,
        height=256,
        rgb1=[0.80, 0.72, 0.60],
        rgb2=[0.74, 0.66, 0.55],
    )
    spec.add_texture(
        name="house/sky",
        type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
        width=64,
        height=64,
        rgb1=[0.75, 0.82, 0.90],
        rgb2=[0.95, 0.95, 0.97],
    )
    floor = spec.add_material(
        name="house/floor", texrepeat=[2, 2], texuniform=True, reflectance=0.0
    )
    floor.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "house/floor_tex"
    spec.add_material(name="house/wall", rgba=[0.93, 0.92, 0.88, 1.0], specular=0.1)
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.45, 0.45, 0.45]
    spec.visual.headlight.specular = [0.05, 0.05, 0.05]
    spec.visual.global_.offwidth = 1280
    spec.visual.global_.offheight = 960
    spec.visual.quality.shadowsize = 0
    for i, direction in enumerate(([0.3, 0.4, -1.0], [-0.4, -0.2, -1.0])):
        spec.worldbody.add_light(
            name=f"house/sun{i}",
            type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
            pos=[5.0, 2.0, 5.0],
            dir=direction,
            diffuse=[0.45, 0.45, 0.43],
            specular=[0.05, 0.05, 0.05],
            castshadow=False,
        )


def _add_cabinet(spec: mujoco.MjSpec, cab: Cabinet, layout: dict) -> None:
    body = spec.worldbody.add_body(
        name=cab.name,
        pos=[cab.center[0], cab.center[1], 0.0],
        quat=quat_from_yaw(math.radians(cab.yaw)).tolist(),
    )
    w, d, h, p = cab.width, cab.depth, cab.height, cab.panel
    hw, hd = w / 2, d / 2
    rgba = cab.rgba
    _box(body, f"{cab.name}/side_l", (0, -hw + p / 2, h / 2), (hd, p / 2, h / 2), rgba)
    _box(body, f"{cab.name}/side_r", (0, hw - p / 2, h / 2), (hd, p / 2, h / 2), rgba)
    _box(body, f"{cab.name}/top", (0, 0, h - p / 2), (hd, hw, p / 2), rgba)
    _box(body, f"{cab.name}/base", (0, 0, 0.015), (hd, hw, 0.015), rgba)
    _box(body, f"{cab.name}/back", (-hd + p / 2, 0, h / 2), (p / 2, hw - p, h / 2 - p), rgba)
    # Shelf between the lower pair and the top drawer, and the divider of the lower pair.
    lower = [dr for dr in cab.drawers if dr.z < 0.1]
    upper = [dr for dr in cab.drawers if dr.z >= 0.1]
    if lower and upper:
        z_shelf = 0.5 * (max(dr.z + dr.height for dr in lower) + min(dr.z for dr in upper))
        _box(body, f"{cab.name}/shelf", (0, 0, z_shelf), (hd, hw - p, 0.01), rgba)
        if len(lower) > 1:
            z_top = z_shelf - 0.01
            _box(
                body,
                f"{cab.name}/divider",
                (0, 0, (0.03 + z_top) / 2),
                (hd, 0.01, (z_top - 0.03) / 2),
                rgba,
            )
    for dr in cab.drawers:
        _add_drawer(body, cab, dr, layout)


DRAWER_FRONT_THICKNESS = 0.018  # m, a drawer's front panel


def _add_drawer(cab_body: mujoco.MjsBody, cab: Cabinet, dr: Drawer, layout: dict) -> None:
    """A drawer: open box behind a front panel, on a damped limited slide along cabinet +x.

    The drawer body origin is the bottom centre of its front face when closed; its judge
    region is the inside of the box, in the drawer frame, so it moves with the drawer.
    """
    name = f"{cab.name}/drawer_{dr.name}"
    body = cab_body.add_body(name=name, pos=[cab.depth / 2, dr.y, dr.z])
    body.add_joint(
        name=f"{name}/slide",
        type=mujoco.mjtJoint.mjJNT_SLIDE,
        axis=[1, 0, 0],
        range=[0.0, cab.travel],
        limited=mujoco.mjtLimited.mjLIMITED_TRUE,
        damping=cab.damping,
        frictionloss=cab.frictionloss,
        armature=0.01,
    )
    t_front, t = DRAWER_FRONT_THICKNESS, 0.01
    depth, width, height = cab.drawer_depth, dr.width, dr.height
    side_h = 0.75 * height
    rgba = cab.rgba
    pieces = [
        (
            "front",
            (-t_front / 2, 0, height / 2),
            (t_front / 2, width / 2, height / 2),
            cab.front_rgba,
        ),
        (
            "bottom",
            (-(depth + t_front) / 2, 0, t / 2),
            ((depth - t_front) / 2, width / 2, t / 2),
            rgba,
        ),
        ("back", (-depth + t / 2, 0, side_h / 2), (t / 2, width / 2 - t, side_h / 2), rgba),
        (
            "side_l",
            (-(depth + t_front) / 2, -width / 2 + t / 2, side_h / 2),
            ((depth - t_front) / 2, t / 2, side_h / 2),
            rgba,
        ),
        (
            "side_r",
            (-(depth + t_front) / 2, width / 2 - t / 2, side_h / 2),
            ((depth - t_front) / 2, t / 2, side_h / 2),
            rgba,
        ),
    ]
    volumes = [8 * hx * hy * hz for _, _, (hx, hy, hz), _ in pieces]
    handle_mass = 0.15
    for (tag, c, half, col), vol in zip(pieces, volumes, strict=True):
        _box(
            body,
            f"{name}/{tag}",
            c,
            half,
            col,
            mass=(cab.drawer_mass - handle_mass) * vol / sum(volumes),
        )
    # Handle: a bar held off the front by two posts, as its own (jointless) child body so a
    # test can push or pull exactly at the handle.
    handle = body.add_body(name=f"{name}/handle", pos=[cab.handle_offset, 0.0, 0.6 * height])
    bar, half_len = cab.handle_bar, cab.handle_length / 2
    _box(
        handle,
        f"{name}/handle_bar",
        (0, 0, 0),
        (bar / 2, half_len, bar / 2),
        cab.handle_rgba,
        mass=0.1,
    )
    for sign, tag in ((1, "a"), (-1, "b")):
        _box(
            handle,
            f"{name}/handle_post_{tag}",
            (-cab.handle_offset / 2, sign * (half_len - bar / 2), 0),
            (cab.handle_offset / 2, bar / 2, bar / 3),
            cab.handle_rgba,
            mass=0.025,
        )
    layout["drawer_joints"][dr.name] = f"{name}/slide"
    layout["drawer_bodies"][dr.name] = name
    layout["drawer_handles"][dr.name] = f"{name}/handle"
    # The whole box behind the front, whatever the drawer's opening; its rim is the front's
    # top (inside the cabinet an object may stand above the sides up to there).
    inner_top = height
    layout["regions"].append(
        DepositRegion(
            place="drawer",
            name=f"drawer_{dr.name}",
            body=name,
            center=(-(depth + t_front) / 2, 0.0, (t + inner_top) / 2),
            half_size=((depth - t_front) / 2 - t, width / 2 - t, (inner_top - t) / 2),
            support_body=name,
        )
    )


OBSTACLE_RGBA = (0.78, 0.36, 0.20, 1.0)


def add_obstacle(
    spec: mujoco.MjSpec,
    name: str,
    center: tuple[float, float],
    size: tuple[float, float, float],
) -> mujoco.MjsGeom:
    """A fixed box on the floor that is not part of the house (a scenario's obstacle)."""
    return _box(
        spec.worldbody,
        f"obstacle/{name}",
        (center[0], center[1], size[2] / 2),
        (size[0] / 2, size[1] / 2, size[2] / 2),
        OBSTACLE_RGBA,
    )


def build_house(spec: mujoco.MjSpec, house: HouseConfig) -> HouseLayout:
    """Add the whole house to ``spec``; return its regions, surfaces, drawers and cameras."""
    _add_visuals(spec)
    wb = spec.worldbody
    floor = wb.add_geom(
        name="house/floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[5.6, 2.6, 0.05],
        pos=[5.0, 2.0, 0.0],
        material="house/floor",
        friction=[1.0, 0.005, 0.0001],
    )
    floor.group = 0
    hh = house.wall_height / 2
    for wall in house.walls:
        x0, y0, x1, y1 = wall.rect
        _box(
            wb,
            f"house/wall_{wall.name}",
            ((x0 + x1) / 2, (y0 + y1) / 2, hh),
            ((x1 - x0) / 2, (y1 - y0) / 2, hh),
            (0.93, 0.92, 0.88, 1.0),
            material="house/wall",
        )
    layout: dict = {
        "regions": [],
        "surfaces": [],
        "drawer_joints": {},
        "drawer_bodies": {},
        "drawer_handles": {},
    }
    top_t, leg = house.table_top_thickness, house.table_leg
    for table in house.tables:
        body = wb.add_body(
            name=f"furniture/{table.name}", pos=[table.center[0], table.center[1], 0.0]
        )
        sx, sy = table.size
        _box(
            body,
            f"{table.name}/top",
            (0, 0, table.height - top_t / 2),
            (sx / 2, sy / 2, top_t / 2),
            table.rgba,
        )
        leg_h = (table.height - top_t) / 2
        for i, (ux, uy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
            _box(
                body,
                f"{table.name}/leg{i}",
                (ux * (sx / 2 - leg), uy * (sy / 2 - leg), leg_h),
                (leg / 2, leg / 2, leg_h),
                table.rgba,
            )
        if table.spawn:
            layout["surfaces"].append(
                Surface(
                    name=table.name,
                    kind="table",
                    room=table.room,
                    z=table.height,
                    min=(table.center[0] - sx / 2, table.center[1] - sy / 2),
                    max=(table.center[0] + sx / 2, table.center[1] + sy / 2),
                    reach_edge=table.reach_edge,
                )
            )
    for block in house.blocks:
        _box(
            wb,
            f"furniture/{block.name}",
            (block.center[0], block.center[1], block.size[2] / 2),
            (block.size[0] / 2, block.size[1] / 2, block.size[2] / 2),
            block.rgba,
        )
    for c in house.containers:
        z0 = 0.0 if c.on == "floor" else house.table(c.on).height
        body = wb.add_body(name=f"place/{c.name}", pos=[c.center[0], c.center[1], z0])
        _open_box(body, f"place/{c.name}", c.size, c.wall, c.bottom, c.rgba)
        inner_h = c.size[2] - c.bottom  # inner bottom to rim
        layout["regions"].append(
            DepositRegion(
                place=c.name,
                name=c.name,
                body="world",
                center=(c.center[0], c.center[1], z0 + c.bottom + inner_h / 2),
                half_size=(c.size[0] / 2 - c.wall, c.size[1] / 2 - c.wall, inner_h / 2),
                support_body=f"place/{c.name}",
            )
        )
    _add_cabinet(spec, house.cabinet, layout)
    for area in house.floor_areas:
        layout["surfaces"].append(
            Surface(name=area.name, kind="floor", room=area.room, z=0.0, min=area.min, max=area.max)
        )
    cams = []
    for cam in house.cameras:
        wb.add_camera(
            name=cam.name,
            pos=list(cam.pos),
            quat=list(camera_quat(np.array(cam.pos), np.array(cam.target))),
            fovy=cam.fovy,
        )
        cams.append(cam.name)
    return HouseLayout(
        regions=tuple(layout["regions"]),
        surfaces=tuple(layout["surfaces"]),
        drawer_joints=layout["drawer_joints"],
        drawer_bodies=layout["drawer_bodies"],
        drawer_handles=layout["drawer_handles"],
        cameras=tuple(cams),
    )
