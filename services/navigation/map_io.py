"""Maps on disk in ROS map_server's format (a PGM image and a YAML description), so a map
built here opens in the ROS tools and a ROS map loads here, plus a PNG for people.

Trinary pixels: 254 free, 0 occupied, 205 unknown (map_server's own saver's values; with
negate 0 they read back as p = (255 - v) / 255: 0.004 < free_thresh, 1.0 >
occupied_thresh, 0.196 between). Image row 0 is the map's top (highest y), our grid's
row 0 its bottom: the saver flips. The YAML is flat, so a tiny writer/reader does
(pyyaml is only a development dependency).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
from quadmanip.services.navigation.grid import GridGeometry

__all__ = [
    "MapFileError",
    "load_map",
    "load_surface",
    "read_map_yaml",
    "save_map",
    "save_surface",
    "surface_path_for",
]

FREE_PIXEL = 254
OCCUPIED_PIXEL = 0
UNKNOWN_PIXEL = 205


class MapFileError(ValueError):
    """A map file that is missing, malformed or inconsistent."""


def _classify(occupancy: np.ndarray, occupied_thresh: float, free_thresh: float) -> np.ndarray:
    """Trinary pixels of an int8 occupancy grid (percent; -1 unknown), map_server's rule."""
    occ = np.asarray(occupancy)
    p = occ.astype(float) / 100.0
    px = np.full(occ.shape, UNKNOWN_PIXEL, dtype=np.uint8)
    known = occ >= 0
    px[known & (p > occupied_thresh)] = OCCUPIED_PIXEL
    px[known & (p < free_thresh)] = FREE_PIXEL
    return px


def _crop(
    occupancy: np.ndarray, geometry: GridGeometry, margin: int
) -> tuple[np.ndarray, GridGeometry]:
    known = np.asarray(occupancy) >= 0
    if not known.any():
        return occupancy, geometry
    rows = np.flatnonzero(known.any(axis=1))
    cols = np.flatnonzero(known.any(axis=0))
    r0, r1 = max(int(rows[0]) - margin, 0), min(int(rows[-1]) + 1 + margin, geometry.height)
    c0, c1 = max(int(cols[0]) - margin, 0), min(int(cols[-1]) + 1 + margin, geometry.width)
    geo = GridGeometry(
        geometry.resolution,
        geometry.origin_x + c0 * geometry.resolution,
        geometry.origin_y + r0 * geometry.resolution,
        c1 - c0,
        r1 - r0,
    )
    return occupancy[r0:r1, c0:c1], geo


def save_map(
    stem: Path | str,
    occupancy: np.ndarray,
    geometry: GridGeometry,
    crop: bool = True,
    margin_cells: int = 10,
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
    picture: bool = True,
) -> dict[str, Path]:
    """Write ``stem.pgm``, ``stem.yaml`` (and ``stem.png`` when ``picture``); returns their
    paths by kind. ``crop`` keeps the known cells plus ``margin_cells`` (the origin moves
    with the crop)."""
    occ = np.asarray(occupancy)
    if occ.shape != geometry.shape:
        raise MapFileError(f"occupancy shape {occ.shape} != grid shape {geometry.shape}")
    if crop:
        occ, geometry = _crop(occ, geometry, margin_cells)
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    pgm = stem.with_suffix(".pgm")
    yaml = stem.with_suffix(".yaml")
    px = _classify(occ, occupied_thresh, free_thresh)[::-1]  # image row 0 = top
    header = (
        f"P5\n# quadmanip map, {geometry.resolution:g} m/pixel\n{px.shape[1]} {px.shape[0]}\n255\n"
    )
    pgm.write_bytes(header.encode("ascii") + np.ascontiguousarray(px).tobytes())
    yaml.write_text(
        f"image: {pgm.name}\n"
        "mode: trinary\n"
        f"resolution: {geometry.resolution!r}\n"
        f"origin: [{geometry.origin_x!r}, {geometry.origin_y!r}, 0.0]\n"
        "negate: 0\n"
        f"occupied_thresh: {occupied_thresh!r}\n"
        f"free_thresh: {free_thresh!r}\n"
    )
    out = {"pgm": pgm, "yaml": yaml}
    if picture:
        out["png"] = _save_picture(stem.with_suffix(".png"), occ, geometry, px[::-1])
    return out


def _save_picture(path: Path, occ: np.ndarray, geometry: GridGeometry, px: np.ndarray) -> Path:
    """An upscaled colour picture: free white, occupied black, unknown grey, uncertain
    cells tinted, a 1 m grid in light blue and the map origin's axes (x red, y green)."""
    import cv2

    scale = max(1, min(8, int(1600 // max(occ.shape))))
    rgb = np.empty(occ.shape + (3,), dtype=np.uint8)
    rgb[:] = (160, 160, 160)
    rgb[px == FREE_PIXEL] = (255, 255, 255)
    rgb[px == OCCUPIED_PIXEL] = (20, 20, 20)
    uncertain = (occ >= 0) & (px == UNKNOWN_PIXEL)
    rgb[uncertain] = (200, 170, 120)
    img = np.repeat(np.repeat(rgb, scale, axis=0), scale, axis=1)
    res = geometry.resolution / scale  # metres per picture pixel
    h, w = img.shape[:2]
    xs = geometry.origin_x + (np.arange(w) + 0.5) * res
    ys = geometry.origin_y + (np.arange(h) + 0.5) * res
    on_x = np.abs(xs - np.round(xs)) < 0.5 * res
    on_y = np.abs(ys - np.round(ys)) < 0.5 * res
    line = (235, 200, 150)  # BGR light blue
    blend = img.astype(np.int32)
    blend[:, on_x] = (blend[:, on_x] + line) // 2
    blend[on_y, :] = (blend[on_y, :] + line) // 2
    img = blend.astype(np.uint8)
    # the map origin's axes, 0.5 m long, where the origin lies on the picture
    c0 = int(round(-geometry.origin_x / res))
    r0 = int(round(-geometry.origin_y / res))
    n = int(round(0.5 / res))
    if 0 <= r0 < h and 0 <= c0 < w:
        img[r0 : r0 + 2, c0 : min(c0 + n, w)] = (0, 0, 230)
        img[r0 : min(r0 + n, h), c0 : c0 + 2] = (0, 170, 0)
    if not cv2.imwrite(str(path), np.ascontiguousarray(img[::-1])):
        raise MapFileError(f"could not write {path}")
    return path


# ---------------------------------------------------------------------------- loading
_REQUIRED = ("image", "resolution", "origin")


def _parse_value(text: str) -> object:
    text = text.strip()
    if text.startswith("[") and text.endswith("]"):
        return [_parse_value(v) for v in text[1:-1].split(",") if v.strip()]
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def read_map_yaml(path: Path) -> dict[str, object]:
    """The flat ``key: value`` pairs of a map_server YAML (numbers, strings, [lists])."""
    out: dict[str, object] = {}
    for n, raw in enumerate(path.read_text().splitlines(), start=1):
        line = raw.split("#", 1)[0].rstrip()
        if not line.strip():
            continue
        m = re.match(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*:\s*(.*)$", line)
        if m is None:
            raise MapFileError(f"{path}:{n}: not a 'key: value' line: {raw!r}")
        out[m.group(1)] = _parse_value(m.group(2))
    return out


def _read_pgm(path: Path) -> np.ndarray:
    """An 8-bit binary (P5) or ASCII (P2) PGM; other images through OpenCV."""
    data = path.read_bytes()
    if data[:2] not in (b"P5", b"P2"):
        import cv2

        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise MapFileError(f"{path}: not an image OpenCV can read")
        return img
    tokens: list[bytes] = []
    pos = 2
    while len(tokens) < 3:
        m = re.compile(rb"\s*(#[^\n]*\n\s*)*([0-9]+)").match(data, pos)
        if m is None:
            raise MapFileError(f"{path}: bad PGM header")
        tokens.append(m.group(2))
        pos = m.end()
    width, height, maxval = (int(t) for t in tokens)
    if width <= 0 or height <= 0 or not 0 < maxval < 256:
        raise MapFileError(f"{path}: unsupported PGM {width}x{height}, maxval {maxval}")
    if data[:2] == b"P2":
        values = np.array(data[pos:].split(), dtype=np.int64)
    else:
        values = np.frombuffer(data[pos + 1 :], dtype=np.uint8)
    if values.size < width * height:
        raise MapFileError(
            f"{path}: header says {width}x{height} = {width * height} pixels, "
            f"data has {values.size}"
        )
    img = values[: width * height].reshape(height, width).astype(np.float64)
    return np.rint(img * 255.0 / maxval).astype(np.uint8)


def load_map(yaml_path: Path | str) -> tuple[np.ndarray, GridGeometry]:
    """(int8 occupancy (-1 unknown, 0..100; row 0 = lowest y), geometry) of a map_server
    map. Modes trinary (default) and scale are read; the origin's yaw must be 0 (our grids
    are axis-aligned with their frame)."""
    yaml_path = Path(yaml_path)
    if not yaml_path.is_file():
        raise MapFileError(f"no map description at {yaml_path}")
    meta = read_map_yaml(yaml_path)
    missing = [k for k in _REQUIRED if k not in meta]
    if missing:
        raise MapFileError(f"{yaml_path}: missing key(s) {', '.join(missing)}")
    try:
        resolution = float(meta["resolution"])  # type: ignore[arg-type]
        origin = [float(v) for v in meta["origin"]]  # type: ignore[union-attr]
        negate = int(meta.get("negate", 0))  # type: ignore[call-overload]
        occ_t = float(meta.get("occupied_thresh", 0.65))  # type: ignore[arg-type]
        free_t = float(meta.get("free_thresh", 0.196))  # type: ignore[arg-type]
    except (TypeError, ValueError) as e:
        raise MapFileError(f"{yaml_path}: bad value: {e}") from e
    mode = str(meta.get("mode", "trinary"))
    if not (resolution > 0 and math.isfinite(resolution)):
        raise MapFileError(f"{yaml_path}: resolution must be positive, got {resolution}")
    if len(origin) != 3:
        raise MapFileError(f"{yaml_path}: origin must be [x, y, yaw], got {origin}")
    if abs(origin[2]) > 1e-9:
        raise MapFileError(f"{yaml_path}: origin yaw {origin[2]} != 0 is not supported")
    if mode not in ("trinary", "scale"):
        raise MapFileError(f"{yaml_path}: mode {mode!r} not supported (trinary, scale)")
    if not 0 <= free_t < occ_t <= 1:
        raise MapFileError(f"{yaml_path}: need 0 <= free_thresh < occupied_thresh <= 1")
    image = Path(str(meta["image"]))
    if not image.is_absolute():
        image = yaml_path.parent / image
    if not image.is_file():
        raise MapFileError(f"{yaml_path}: image {image} not found")
    px = _read_pgm(image)
    p = px.astype(float) / 255.0 if negate else (255.0 - px.astype(float)) / 255.0
    occ = np.full(px.shape, -1, dtype=np.int8)
    occ[p > occ_t] = 100
    occ[p < free_t] = 0
    if mode == "scale":
        mid = (p >= free_t) & (p <= occ_t)
        occ[mid] = np.rint(99.0 * (p[mid] - free_t) / (occ_t - free_t)).astype(np.int8)
    geo = GridGeometry(resolution, origin[0], origin[1], px.shape[1], px.shape[0])
    return occ[::-1].copy(), geo


# ------------------------------------------------------------------ the fine surface raster
def surface_path_for(map_yaml: Path | str) -> Path:
    """The fine surface raster that belongs to a map: ``NAME_surface.yaml`` beside
    ``NAME.yaml`` (itself a map_server map: surface cells occupied, the rest free)."""
    p = Path(map_yaml)
    return p.with_name(p.stem + "_surface.yaml")


def save_surface(map_stem: Path | str, mask: np.ndarray, geometry: GridGeometry) -> Path:
    """Write the mapping's surface raster (True: a surface seen there; see
    ``OnlineSlam.surface``) beside the map ``map_stem``; returns its YAML's path."""
    mask = np.asarray(mask, dtype=bool)
    stem = surface_path_for(Path(map_stem).with_suffix(".yaml")).with_suffix("")
    occ = np.where(mask, 100, 0).astype(np.int8)
    return save_map(stem, occ, geometry, crop=False, picture=False)["yaml"]


def load_surface(map_yaml: Path | str) -> tuple[np.ndarray, GridGeometry] | None:
    """The surface raster saved beside the map ``map_yaml`` (mask, geometry), or None when
    the map has none (a map from elsewhere: localisation then refines on the map itself)."""
    path = surface_path_for(map_yaml)
    if not path.is_file():
        return None
    occ, geo = load_map(path)
    mask = occ >= 65
    if not mask.any():
        raise MapFileError(f"{path}: marks no surface")
    return mask, geo
