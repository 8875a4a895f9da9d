# SPDX-License-Identifier: BSD-3-Clause
"""Scene understanding, part 3: plane heightmaps and a low-poly room model.

A heightmap images one planar segment: pixel (row, col) covers the square
``origin + (col + [0, 1]) * pixel * u + (row + [0, 1]) * pixel * v`` on the plane, and holds the
median signed distance [m] of the points that project into it (positive into the room, so a
radiator on a wall or a lamp on a ceiling stands out). Pixels without points are holes.

On disk: a 16-bit PNG (``value = round(height / scale) + 32768``, holes 0, ``scale`` 0.1 mm, so
+-3.27 m) beside a JSON with the plane, pixel size, origin, axes and the encoding.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .planes import Plane

HOLE = 0
ZERO = 32768
SCALE_M = 1e-4  # [m] per PNG unit
CLASS_NAMES = ("ceiling", "floor", "wall", "other")


@dataclass
class Heightmap:
    """Heightmap of one plane.

    height : (H, W) float32 [m], NaN = hole; pixel : edge [m]; origin : (3,) [m] of the corner of
    pixel (0, 0); axes : (2, 3) unit u (columns), v (rows); normal, offset : the plane;
    counts : (H, W) int32 points per pixel; label : class of the plane
    """

    height: np.ndarray
    pixel: float
    origin: np.ndarray
    axes: np.ndarray
    normal: np.ndarray
    offset: float
    counts: np.ndarray
    label: int

    def pixel_centres(self) -> np.ndarray:
        """(H, W, 3) 3-D centres of the pixels, on the plane [m]."""
        H, W = self.height.shape
        c = (np.arange(W) + 0.5) * self.pixel
        r = (np.arange(H) + 0.5) * self.pixel
        return (self.origin + c[None, :, None] * self.axes[0] + r[:, None, None] * self.axes[1])

    def points(self) -> np.ndarray:
        """(K, 3) 3-D points of the non-hole pixels (centre lifted by its height) [m]."""
        m = np.isfinite(self.height)
        return self.pixel_centres()[m] + self.height[m][:, None] * self.normal

    def metadata(self) -> dict:
        return {
            "label": int(self.label), "class": CLASS_NAMES[self.label],
            "plane": {"normal": self.normal.tolist(), "offset": float(self.offset)},
            "pixel_size_m": float(self.pixel), "origin_m": self.origin.tolist(),
            "axes": {"u_columns": self.axes[0].tolist(), "v_rows": self.axes[1].tolist()},
            "shape": list(self.height.shape),
            "encoding": {"png": "16-bit grey", "height_m": f"(value - {ZERO}) * {SCALE_M}",
                         "hole_value": HOLE},
            "holes": int((~np.isfinite(self.height)).sum()),
        }

    def save(self, png_path) -> None:
        """Write ``png_path`` (16-bit) and ``png_path`` with .json."""
        from PIL import Image

        png_path = Path(png_path)
        v = np.full(self.height.shape, HOLE, np.uint16)
        m = np.isfinite(self.height)
        v[m] = np.clip(np.round(self.height[m] / SCALE_M) + ZERO, 1, 65535).astype(np.uint16)
        Image.fromarray(v).save(png_path)
        png_path.with_suffix(".json").write_text(json.dumps(self.metadata(), indent=1))

    @classmethod
    def load(cls, png_path) -> "Heightmap":
        from PIL import Image

        png_path = Path(png_path)
        meta = json.loads(png_path.with_suffix(".json").read_text())
        v = np.asarray(Image.open(png_path)).astype(np.int64)
        h = np.where(v == HOLE, np.nan, (v - ZERO) * SCALE_M).astype(np.float32)
        return cls(h, meta["pixel_size_m"], np.array(meta["origin_m"]),
                   np.array([meta["axes"]["u_columns"], meta["axes"]["v_rows"]]),
                   np.array(meta["plane"]["normal"]), meta["plane"]["offset"],
                   (v != HOLE).astype(np.int32), meta["label"])


def plane_heightmap(points, plane: Plane, *, pixel: float = 0.05, behind: float = 0.10,
                    relief: float = 0.40, margin: float = 0.10, normals=None,
                    facing_deg: float = 60.0) -> Heightmap:
    """Heightmap of one plane from a cloud.

    Parameters
    ----------
    points : (N, 3) [m], the whole cloud (all classes: things on a wall are its relief)
    plane : the segment (its points fix the extent)
    pixel : pixel edge [m]
    behind, relief : points from -behind to +relief [m] off the plane count
    margin : extent beyond the segment's points [m]
    normals : (N, 3) unit normals of ``points`` or None (computed from voxel moments)
    facing_deg : only points whose normal is within this angle of the plane's count: the sides of
        a cabinet standing on the floor are not the floor's relief
    """
    P = np.asarray(points, np.float64)
    seg_uv = plane.to_plane_coords(P[plane.indices])
    lo = seg_uv.min(0) - margin
    hi = seg_uv.max(0) + margin
    W, H = (np.ceil((hi - lo) / pixel).astype(int) + 1).tolist()
    # candidates: near the plane, inside the box
    d = plane.distance(P)
    near = np.flatnonzero((d > -behind) & (d < relief))
    if normals is None:
        from ..preprocess import point_normals

        nrm = point_normals(P[near].astype(np.float32), 0.05)
    else:
        nrm = np.asarray(normals)[near]
    near = near[np.abs(nrm @ plane.normal) > np.cos(np.deg2rad(facing_deg))]
    uv = plane.to_plane_coords(P[near])
    col = np.floor((uv[:, 0] - lo[0]) / pixel).astype(np.int64)
    row = np.floor((uv[:, 1] - lo[1]) / pixel).astype(np.int64)
    ok = (col >= 0) & (col < W) & (row >= 0) & (row < H)
    # only pixels next to the segment's own points (not the plane's far extension)
    seg_pix = np.zeros((H, W), bool)
    sc = np.floor((seg_uv - lo) / pixel).astype(np.int64)
    seg_pix[sc[:, 1], sc[:, 0]] = True
    from scipy import ndimage

    # things on the surface hide it: fill the segment's holes so their relief is kept
    seg_pix = ndimage.binary_fill_holes(ndimage.binary_closing(seg_pix, iterations=2) | seg_pix)
    seg_pix = ndimage.binary_dilation(seg_pix, iterations=1)
    ok &= seg_pix[np.clip(row, 0, H - 1), np.clip(col, 0, W - 1)]
    flat = row[ok] * W + col[ok]
    dist = d[near][ok]
    height = np.full(H * W, np.nan, np.float32)
    counts = np.bincount(flat, minlength=H * W).astype(np.int32)
    if len(flat):
        order = np.lexsort((dist, flat))  # by pixel, then by distance: medians by position
        fs, ds = flat[order], dist[order]
        starts = np.flatnonzero(np.r_[True, fs[1:] != fs[:-1]])
        ends = np.r_[starts[1:], len(fs)]
        mid_lo = starts + (ends - starts - 1) // 2
        mid_hi = starts + (ends - starts) // 2
        height[fs[starts]] = 0.5 * (ds[mid_lo] + ds[mid_hi])
    origin = plane.origin + lo[0] * plane.axes[0] + lo[1] * plane.axes[1]
    return Heightmap(height.reshape(H, W), float(pixel), origin, plane.axes.copy(),
                     plane.normal.copy(), float(plane.offset), counts.reshape(H, W), plane.label)


# ------------------------------------------------------------------------------------ low-poly
def _triangulate(poly: np.ndarray) -> list[tuple[int, int, int]]:
    """Ear clipping of a simple 2-D polygon (K, 2); returns index triples."""
    n = len(poly)
    if n < 3:
        return []
    scale = float(np.ptp(poly, 0).max()) or 1.0
    eps = 1e-9 * scale * scale
    # drop repeated and collinear corners first (they block every ear)
    idx = list(range(n))
    changed = True
    while changed and len(idx) > 3:
        changed = False
        for k in range(len(idx)):
            a, b, c = poly[idx[k - 1]], poly[idx[k]], poly[idx[(k + 1) % len(idx)]]
            if abs((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])) <= eps:
                idx.pop(k)
                changed = True
                break
    n = len(idx)
    q = poly[idx]
    area = 0.5 * np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1])
    if area < 0:
        idx.reverse()

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    tris = []
    guard = 0
    while len(idx) > 3 and guard < 10 * n:
        guard += 1
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = poly[i0], poly[i1], poly[i2]
            if cross(a, b, c) <= eps:
                continue
            inside = False
            for j in idx:
                if j in (i0, i1, i2):
                    continue
                p = poly[j]
                if cross(a, b, p) > eps and cross(b, c, p) > eps and cross(c, a, p) > eps:
                    inside = True
                    break
            if not inside:
                tris.append((i0, i1, i2))
                idx.pop(k)
                break
        else:
            break  # degenerate remainder
    if len(idx) == 3:
        tris.append(tuple(idx))
    return tris


def low_poly_mesh(planes: list[Plane]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangulated plane outlines: vertices (V, 3) [m], triangles (T, 3), class per triangle."""
    V, T, C = [], [], []
    base = 0
    for pl in planes:
        if len(pl.outline) < 3:
            continue
        uv = pl.to_plane_coords(pl.outline)
        tris = _triangulate(uv)
        if not tris:
            continue
        V.append(pl.outline)
        T.append(np.asarray(tris, np.int64) + base)
        C.append(np.full(len(tris), pl.label, np.int32))
        base += len(pl.outline)
    if not V:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int32)
    return np.concatenate(V), np.concatenate(T), np.concatenate(C)


CLASS_COLOURS = np.array([[70, 130, 230], [200, 160, 60], [120, 190, 120], [200, 80, 80]], np.uint8)


def write_mesh_ply(path, vertices: np.ndarray, triangles: np.ndarray, classes: np.ndarray) -> None:
    """Binary PLY mesh with a per-face ``class`` and colour (MeshLab/CloudCompare/Open3D open it)."""
    v = np.asarray(vertices, "<f4")
    face = np.empty(len(triangles), dtype=[("n", "u1"), ("i", "<i4", (3,)), ("class", "u1"),
                                           ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    face["n"] = 3
    face["i"] = triangles
    face["class"] = classes
    rgb = CLASS_COLOURS[np.clip(classes, 0, 3)]
    face["red"], face["green"], face["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    header = ("ply\nformat binary_little_endian 1.0\ncomment tripod low-poly room model; "
              "class: 0 ceiling, 1 floor, 2 wall, 3 other\n"
              f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {len(face)}\nproperty list uchar int vertex_indices\n"
              "property uchar class\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
              "end_header\n")
    with open(path, "wb") as fh:
        fh.write(header.encode())
        fh.write(v.tobytes())
        fh.write(face.tobytes())


def truth_heightmap(hm: Heightmap, raycasting_scene, behind: float = 0.10, relief: float = 0.40,
                    sub: int = 4) -> np.ndarray:
    """The heightmap the true surface would give: for every pixel the median over sub x sub rays
    of the first surface met along the normal from ``behind`` under the plane (Open3D
    ``RaycastingScene`` of the mesh); NaN where nothing lies within the relief band."""
    import open3d as o3d

    H, W = hm.height.shape
    off = (np.arange(sub) + 0.5) / sub
    c = (np.arange(W)[:, None] + off[None]).ravel() * hm.pixel
    r = (np.arange(H)[:, None] + off[None]).ravel() * hm.pixel
    centres = hm.origin + c[None, :, None] * hm.axes[0] + r[:, None, None] * hm.axes[1]
    start = centres.reshape(-1, 3) - behind * hm.normal
    rays = np.concatenate([start, np.broadcast_to(hm.normal, start.shape)], 1).astype(np.float32)
    t = raycasting_scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy() - behind
    t = np.where(t < relief, t, np.nan).reshape(H, sub, W, sub).transpose(0, 2, 1, 3)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return np.nanmedian(t.reshape(H, W, sub * sub), axis=2)


def relief_rmse(hm: Heightmap, raycasting_scene, behind: float = 0.10, relief: float = 0.40,
                edge_pixels: int = 1) -> tuple[float, int]:
    """RMSE [m] of a heightmap against :func:`truth_heightmap` of the mesh, over the pixels that
    both have; pixels within ``edge_pixels`` of a hole or the border are left out (their few
    points see the surface at grazing angles). Returns (rmse, pixels compared)."""
    from scipy import ndimage

    truth = truth_heightmap(hm, raycasting_scene, behind, relief)
    valid = np.isfinite(hm.height)
    if edge_pixels:
        valid = ndimage.binary_erosion(valid, iterations=edge_pixels, border_value=0)
    valid &= np.isfinite(truth)
    if not valid.any():
        return float("nan"), 0
    err = hm.height[valid] - truth[valid]
    return float(np.sqrt(np.mean(err ** 2))), int(valid.sum())


def register_by_heightmaps(source, target, **kwargs):
    """Registration by heightmap matching; see
    :func:`tripod_processor.scene.heightmap_registration.register_by_heightmaps` (re-exported here)."""
    from .heightmap_registration import register_by_heightmaps as _register

    return _register(source, target, **kwargs)
