# SPDX-License-Identifier: BSD-3-Clause
"""Predictive geometry mode: ordered sensor scans coded point by point in spherical coordinates.

Lidar scans stored in acquisition order (a VLP-16 revolution, a tilting scanner's columns, a
fragment in firing order in the sensor frame) are far more regular about the sensor than on any
voxel grid: consecutive points share or step their angles, and each range resembles the range in
the same scan row one sweep earlier. This mode (MPEG G-PCC's *predictive geometry* with the
angular mode, in spirit) exploits that:

1. **Origin**: the given one (a PCD ``VIEWPOINT``, ``--origin``), else (0, 0, 0).
2. **Lattices** (:func:`plan_grid`): the elevations are tested for a small set of distinct values
   (the lasers of a spinning lidar, the steps of a tilting scanner); when found, each point codes
   its index in that table and the elevation is reconstructed exactly. The ranges are tested for
   a common step (a sensor's range resolution, e.g. 1 cm or 2 mm); when found, the range
   quantiser uses a multiple of it, so that range is exact (lossless) whenever the requested
   error allows. Otherwise angles and ranges get plain uniform steps.
3. **Steps from the error bound**: range half-step <= 0.9 e and angular error <= 0.43 e at the
   farthest point (in quadrature: sqrt(0.81 + 0.185) < 1); the encoder then measures the real
   worst-case error of the reconstruction and retries with a conservative split (0.7 + 0.3,
   a plain sum) if it exceeds e. It never returns a stream that breaks the bound.
4. **Coding** (C++, ``predictive_codec.cpp``): the integers are predicted from earlier points
   (elevation and azimuth steps; the range by LOCO-I's median edge detector over the scan seen
   as an image) and the residuals range-coded with online-adaptive binary contexts.

The points come back in their input order, all of them (duplicates included): unlike the octree
mode nothing is merged. A cloud with no such structure codes badly in this mode; the codec's
``auto`` mode then keeps the octree (see :func:`..codec.encode`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

CODEC_NAME = "predictive-sph2"  # sph1 + the per-laser model and the row azimuth predictor
CODEC_NAMES = (CODEC_NAME, "predictive-sph1")  # what the decoder reads (sph1: PR of issue 8)
MAX_EL_TABLE = 4096  # most distinct elevations taken as a lattice (a table costs 8 B each)
MAX_LASERS = 256  # most lasers of a per-laser model (each costs 16 B and a test per point)
_RANGE_SPLIT, _ANGLE_SPLIT = 0.9, 0.43  # error split in quadrature (first try)
_SAFE_SPLIT = (0.7, 0.3)  # a plain sum: always within the bound (fall-back try)


@dataclass
class ScanGrid:
    """The spherical quantisation grid of one file (everything the decoder needs but the stream).

    ``az_count`` azimuth steps per turn; ``el_table`` (sorted [rad]) or ``el_step`` [rad];
    ``row_shift``: without a table, the scan row of elevation index e is e >> row_shift.
    """

    origin: np.ndarray  # (3,) float64 [m]
    range_step: float  # [m]
    az_count: int
    el_step: float  # [rad]
    el_table: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (T,) float64 [rad]
    row_shift: int = 0
    range_lattice: float = 0.0  # [m], 0 = none detected (information only)
    el_uniform: tuple[float, float] | None = None  # (start, step) [rad] of a uniform table
    z_table: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (T,) [m] per laser
    az_predictor: int = 1  # 0: previous azimuth (sph1 files); 1: adaptive row predictor
    az_lattice: int = 0  # azimuth lattice steps per turn, 0 = none (information only)

    def native(self):
        """The grid as the C++ codec takes it (``_ext._SphericalGrid``)."""
        from .. import _ext

        g = _ext._SphericalGrid()
        g.origin = tuple(float(v) for v in np.asarray(self.origin, np.float64).reshape(3))
        g.range_step, g.az_count, g.el_step = (float(self.range_step), int(self.az_count),
                                               float(self.el_step))
        g.el_table = np.asarray(self.el_table, np.float64).tolist()
        g.z_table = np.asarray(self.z_table, np.float64).tolist()
        g.row_shift, g.az_predictor = int(self.row_shift), int(self.az_predictor)
        return g

    def header(self) -> dict:
        """Header fields; a uniform elevation table is stored as el_uniform = (start, step)."""
        out = {"origin": [float(v) for v in self.origin], "range_step": float(self.range_step),
               "az_count": int(self.az_count), "el_step": float(self.el_step),
               "el_table_len": int(len(self.el_table)), "row_shift": int(self.row_shift),
               "range_lattice": float(self.range_lattice),
               "laser_z": bool(len(self.z_table)), "az_predictor": int(self.az_predictor),
               "az_lattice": int(self.az_lattice)}
        if self.el_uniform is not None:
            out["el_uniform"] = [float(v) for v in self.el_uniform]
        return out

    def table_section(self) -> bytes:
        """The elevation table section: float64 LE elevations [rad] (none for no table or a
        uniform one), then float64 LE laser heights [m] with the per-laser model."""
        out = b"" if self.el_uniform is not None else np.ascontiguousarray(
            self.el_table, "<f8").tobytes()
        return out + np.ascontiguousarray(self.z_table, "<f8").tobytes()

    @classmethod
    def from_header(cls, header: dict, section: bytes) -> "ScanGrid":
        n, uniform = int(header["el_table_len"]), None
        sph1 = header.get("codec") == "predictive-sph1"
        laser_z = not sph1 and bool(header["laser_z"])
        n_z = n if laser_z else 0
        if "el_uniform" in header:
            start, delta = (float(v) for v in header["el_uniform"])
            table, uniform, expected = uniform_table(start, delta, n), (start, delta), 0
        else:
            table = np.frombuffer(section[:8 * n], "<f8").astype(np.float64)
            expected = 8 * n
        z_table = np.frombuffer(section[expected:], "<f8").astype(np.float64)
        diffs = np.diff(table)
        if (len(section) != expected + 8 * n_z or len(table) != n
                or not np.all(diffs >= 0 if laser_z else diffs > 0)
                or not np.isfinite(z_table).all()):
            raise ValueError("bad elevation table")
        return cls(np.asarray(header["origin"], np.float64).reshape(3),
                   float(header["range_step"]), int(header["az_count"]),
                   float(header["el_step"]), table, int(header["row_shift"]),
                   float(header.get("range_lattice", 0.0)), uniform, z_table,
                   0 if sph1 else int(header["az_predictor"]), int(header.get("az_lattice", 0)))


def elevation_table(elevation: np.ndarray, tol_rad: float, max_entries: int = MAX_EL_TABLE
                    ) -> tuple[np.ndarray, float, tuple[float, float] | None] | None:
    """(sorted table of distinct elevations [rad], worst deviation [rad], (start, step) [rad]
    when the table is uniform, else None), or None when there is no such table.

    Elevations within ``tol_rad`` of each other form one entry (its mid-range value); the table
    is accepted when it has at most ``max_entries`` (and at most N/8) entries, none wider than
    2 ``tol_rad``. A table within ``tol_rad / 2`` of a uniform lattice becomes that lattice.
    """
    n = len(elevation)
    if n == 0:
        return None
    limit = min(max_entries, max(n // 8, 1))
    # cheap rejection on a subsample first: a continuous elevation has too many distinct values
    sub = np.sort(elevation[:: max(1, n // 20000)])
    if np.count_nonzero(np.diff(sub) > tol_rad) + 1 > limit:
        return None
    s = np.sort(elevation)
    cuts = np.flatnonzero(np.diff(s) > tol_rad) + 1
    if len(cuts) + 1 > limit:
        return None
    lo, hi = s[np.r_[0, cuts]], s[np.r_[cuts, n] - 1]
    if (hi - lo).max() > 2 * tol_rad:
        return None
    table, lattice = 0.5 * (lo + hi), None
    if len(table) >= 3:  # a uniform lattice is stored as (start, step) instead of every entry
        delta, start = (float(v) for v in np.polyfit(np.arange(len(table)), table, 1))
        uniform = uniform_table(start, delta, len(table))
        if np.abs(uniform - table).max() <= 0.5 * tol_rad:
            table, lattice = uniform, (start, delta)
    if len(table) == 1:
        dev = np.abs(s - table[0])
    else:
        idx = np.clip(np.searchsorted(table, s), 1, len(table) - 1)
        dev = np.minimum(np.abs(s - table[idx - 1]), np.abs(s - table[idx]))
    return table, float(dev.max()), lattice


def nearest_laser(h: np.ndarray, z: np.ndarray, el_table: np.ndarray, z_table: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(index (N,) of the nearest laser, distance (N,) [m] to its beam cone) of points at
    horizontal range ``h`` [m] and height ``z`` [m] about the origin; laser j's cone, in the
    (h, z) half-plane, is the ray from (0, z_table[j]) at elevation el_table[j] (the rule the
    C++ quantiser applies)."""
    c, s_ = np.cos(el_table), np.sin(el_table)
    idx = np.empty(len(h), np.int64)
    dist = np.empty(len(h))
    chunk = max(1, (1 << 22) // max(len(el_table), 1))  # bounded memory for big tables
    for i in range(0, len(h), chunk):
        d = np.abs((z[i:i + chunk, None] - z_table) * c - h[i:i + chunk, None] * s_)
        idx[i:i + chunk] = d.argmin(1)
        dist[i:i + chunk] = np.take_along_axis(d, idx[i:i + chunk, None], 1)[:, 0]
    return idx, dist


def laser_table(h: np.ndarray, z: np.ndarray, tol_rad: float, max_lasers: int = MAX_LASERS
                ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Per-laser model of a multi-beam spinning lidar in its own frame: (elevations (T,) [rad]
    sorted, heights (T,) [m] of each laser's beam centre on the spin axis, worst angular
    deviation [rad] of a point from its laser's cone), or None when the points do not lie on
    such cones to within ``tol_rad``.

    With a vertical offset z_j a laser's points satisfy z = z_j + h tan(el_j), so their
    elevation about the origin varies with range and no elevation table fits them. The
    candidates come from the far points (there z_j / h is smallest): their elevations split
    into clusters at gaps wider than a fixed fraction of the smallest laser spacing seen in
    practice; each cluster's line z = z_j + h tan(el_j) is fitted by least squares, every point
    is assigned to its nearest cone and the lines refitted (twice); the model is accepted only
    if every point lies within ``tol_rad`` of its cone (checked on a subsample first).
    """
    n = len(h)
    if n < 64:
        return None
    limit = min(max_lasers, max(n // 64, 1))
    sub = slice(None, None, max(1, n // 20000))
    hs, zs = h[sub], z[sub]
    for quantile in (0.75, 0.9):
        far = hs >= np.quantile(hs, quantile)
        el = np.sort(np.arctan2(zs[far], hs[far]))
        if len(el) < 8:
            return None
        cuts = np.flatnonzero(np.diff(el) > 2e-3) + 1  # [rad]; lasers >= 0.33 deg apart
        if len(cuts) + 1 > limit:
            return None
        centres = np.array([b.mean() for b in np.split(el, cuts)])
        model = _fit_lasers(hs, zs, np.tan(centres), np.zeros(len(centres)), tol_rad)
        if model is None:
            continue
        model = _fit_lasers(h, z, np.tan(model[0]), model[1], tol_rad)  # all the points
        if model is not None:
            return model
    return None


def _fit_lasers(h, z, tan_el, z0, tol_rad, rounds: int = 3):
    """Refine lines z = z0 + h tan_el by assignment and least squares; the model, sorted, if
    every point ends within ``tol_rad`` of its cone, else None."""
    r = np.maximum(np.hypot(h, z), 1e-9)
    for _ in range(rounds):
        idx, dist = nearest_laser(h, z, np.arctan(tan_el), z0)
        for j in range(len(tan_el)):
            sel = idx == j
            if np.count_nonzero(sel) >= 3 and np.ptp(h[sel]) > 0:
                a = np.stack([h[sel], np.ones(np.count_nonzero(sel))], 1)
                (tan_el[j], z0[j]), *_ = np.linalg.lstsq(a, z[sel], rcond=None)
    el = np.arctan(tan_el)
    idx, dist = nearest_laser(h, z, el, z0)
    used = np.unique(idx)
    dev = float((dist / r).max())
    if dev > tol_rad:
        return None
    order = used[np.argsort(el[used], kind="stable")]
    return el[order], z0[order], dev


def angle_lattice(az: np.ndarray, tol_rad: float = 2e-6, max_count: int = 1 << 24
                  ) -> tuple[int, float] | None:
    """(M, worst deviation [rad]) when every azimuth is within ``tol_rad`` of a multiple of
    2 pi / M (a sensor's encoder resolution: the VLP-16's 0.01 deg, M = 36000), else None."""
    if len(az) < 16:
        return None
    gaps = np.diff(np.sort(az[:: max(1, len(az) // 20000)]))
    gaps = gaps[gaps > 4 * tol_rad]
    # a lattice much finer than 20 tol_rad would fit any angles (20: chance 1/10 per point)
    if len(gaps) == 0 or gaps.min() < 20 * tol_rad:
        return None
    # the smallest step: each gap is good to only 2 tol_rad, so M = 2 pi / step is tested over
    # its whole uncertainty, nearest first, on a small subsample, then on every point
    step = float(np.median(gaps[gaps < 1.5 * gaps.min()]))
    probe = az[:: max(1, len(az) // 2000)]
    few = probe[:: max(1, len(probe) // 32)]  # a subset of the probe: screens all M at once
    for step in (step, step / 2) if step >= 40 * tol_rad else (step,):
        m0 = 2 * math.pi / step
        spread = int(math.ceil(m0 * 4 * tol_rad / step)) + 1
        cands = np.array(sorted(range(max(2, int(m0) - spread), int(m0) + spread + 2),
                                key=lambda v: abs(v - m0)), dtype=np.int64)
        cands = cands[cands <= max_count]
        if len(cands) == 0:
            continue
        u = few[None, :] * (cands[:, None] / (2 * math.pi))
        screen = np.abs(u - np.round(u)).max(axis=1) * (2 * math.pi) / cands <= tol_rad
        for m in cands[screen].tolist():
            if _lattice_dev(probe, m) > tol_rad:
                continue
            dev = _lattice_dev(az, m)
            if dev <= tol_rad:
                return m, dev
    return None


def _lattice_dev(az: np.ndarray, m: int) -> float:
    u = az * (m / (2 * math.pi))
    return float(np.abs(u - np.round(u)).max()) * 2 * math.pi / m


def uniform_table(start: float, delta: float, count: int) -> np.ndarray:
    """The elevation table start + i delta, i < count [rad] (the same float64s everywhere)."""
    return start + np.arange(count, dtype=np.float64) * delta


def range_lattice(rng: np.ndarray, tol_m: float = 2e-5) -> tuple[float, float] | None:
    """(step [m], worst deviation [m]) when every range is a multiple of one step, else None.

    The step is the smallest gap between the distinct ranges of a subsample, refined by least
    squares; it is accepted only if all ranges lie within ``tol_m`` (float32 storage) of a
    multiple and it is at least 50 ``tol_m``.
    """
    pos = rng[rng > 0]
    if len(pos) < 16:
        return None
    sub = np.unique(np.round(pos[:: max(1, len(pos) // 20000)] / tol_m))
    gaps = np.diff(sub) * tol_m
    gaps = gaps[gaps > 2 * tol_m]
    if len(gaps) == 0:
        return None
    step = float(gaps.min())
    if step < 50 * tol_m:
        return None
    k = np.round(pos / step)
    step = float((k * pos).sum() / (k * k).sum())
    dev = float(np.abs(pos - np.round(pos / step) * step).max())
    if dev > tol_m + 2e-7 * float(pos.max()):
        return None
    return step, dev


def plan_grid(spherical: np.ndarray, max_error: float, origin: np.ndarray,
              split: tuple[float, float] = (_RANGE_SPLIT, _ANGLE_SPLIT), az_exact: bool = False,
              cache: dict | None = None) -> ScanGrid | None:
    """The spherical grid that keeps every point within ``max_error`` [m] (see module doc), or
    None when the bound is below the resolution of float32 coordinates.

    Parameters
    ----------
    spherical : (N, 3) float64 (range [m], azimuth [rad], elevation [rad]) about ``origin``
    az_exact : with an azimuth lattice and an elevation table, keep the lattice exactly and give
        the range the rest of the bound (else: the coarsest lattice subset within the angular
        share of the bound). Which is smaller depends on the scan (a real VLP-16's interpolated
        azimuths favour the subset at coarse steps, a simulated one the exact lattice), so
        :func:`encode_points` tries both.
    cache : a dict kept between calls on the same points (the detections are reused)
    """
    cache = {} if cache is None else cache
    rng, az, el = spherical[:, 0], spherical[:, 1], spherical[:, 2]
    r_max = max(float(rng.max(initial=0.0)), 1e-9)
    # float32 output: the decoded coordinates carry their own rounding
    e = max_error - 4 * float(np.spacing(np.float32(r_max + float(np.abs(origin).max()))))
    if e <= 0:
        return None
    first_try = split == (_RANGE_SPLIT, _ANGLE_SPLIT)
    e_range, e_angle = split[0] * e, split[1] * e
    h = rng * np.cos(el)
    h_max = max(float(h.max(initial=0.0)), 1e-9)  # farthest horizontal range
    # 1. elevations: a table about the origin (lasers, a tilting scanner's steps), else a
    # per-laser model (lasers with vertical offsets), else a uniform step
    angle = e_angle / r_max  # [rad] allowed angular error at the farthest point
    tol = min(2e-5, 0.05 * angle)
    if cache.get("tol") != tol:
        cache.clear()
        cache["tol"] = tol
        table = elevation_table(el, tol_rad=tol)
        el_uniform, z_table, ranges = None, np.zeros(0), rng
        if table is not None:
            el_table, el_dev, el_uniform = table
        elif (lasers := laser_table(h, rng * np.sin(el), tol)) is not None:
            el_table, z_table, el_dev = lasers
            idx, _ = nearest_laser(h, rng * np.sin(el), el_table, z_table)
            ranges = np.hypot(h, rng * np.sin(el) - z_table[idx])  # from each laser's centre
        else:
            el_table, el_dev = np.zeros(0), 0.0
        cache["angles"] = el_table, el_dev, el_uniform, z_table, ranges
        # 2. azimuths: a sensor's encoder lattice, kept exactly where the bound allows
        cache["az_lattice"] = angle_lattice(az)
        cache["range_lattice"] = range_lattice(ranges)
    el_table, el_dev, el_uniform, z_table, ranges = cache["angles"]
    r_max = max(r_max, float(ranges.max(initial=0.0)))
    az_lattice = cache["az_lattice"]
    if len(el_table):
        az_err = max(angle - el_dev, 0.5 * angle) * r_max / h_max
        el_step, row_shift = 0.0, 0
    else:
        az_err = angle / math.sqrt(2) * r_max / h_max
        el_step = 2 * angle / math.sqrt(2)
        # scan rows for the range predictor: elevation bins of about 0.25 deg
        row_shift = max(0, int(math.floor(math.log2(max(math.radians(0.25) / el_step, 1.0)))))
    az_count = min(math.ceil(2 * math.pi / (2 * az_err)), 1 << 40)
    if az_lattice is not None:
        m_count, az_dev = az_lattice
        # the coarsest lattice subset (every m-th step, m dividing M) within the error
        m = 1 if az_exact and len(el_table) else max(
            (d for d in _divisors(m_count) if d * math.pi / m_count + az_dev <= az_err),
            default=1)
        az_count = m_count // m
        if m == 1 and len(el_table):
            # exact azimuth on an exact elevation table: the angles take only their (tiny)
            # deviations, the range gets the rest of the bound (a plain sum: always safe)
            used = el_dev * r_max + az_dev * h_max
            e_range = max(e - used, 0.0) * (1.0 if first_try else 0.95)
    # 3. ranges: a multiple of a detected lattice (e.g. 2 mm), exact where the bound allows
    lattice = cache["range_lattice"]
    if lattice is not None:
        step, dev = lattice
        m = max(1, math.floor((2 * (e_range - dev)) / step)) if e_range > dev else 1
        range_step, lattice_step = m * step, step
    else:
        range_step, lattice_step = 2 * e_range, 0.0
    if not range_step > 0:
        return None
    return ScanGrid(np.asarray(origin, np.float64), float(range_step), int(max(az_count, 2)),
                    float(el_step), np.ascontiguousarray(el_table, np.float64), row_shift,
                    float(lattice_step), el_uniform, np.ascontiguousarray(z_table, np.float64),
                    1, 0 if az_lattice is None else int(az_lattice[0]))


def _divisors(n: int) -> list[int]:
    small = [d for d in range(1, math.isqrt(n) + 1) if n % d == 0]
    return sorted(set(small + [n // d for d in small]))


def encode_points(points: np.ndarray, max_error: float, origin=None, num_threads: int = 0
                  ) -> tuple[bytes, ScanGrid, int, float, tuple[float, float, float]] | None:
    """Code finite ``points`` (N, 3) float32 [m] in order; (stream, grid, checksum, max error [m],
    estimated bits on (elevation, azimuth, range)), or None when no grid keeps the bound
    (coordinates too coarse for it; the octree then takes the cloud)."""
    from .. import _ext

    o = np.zeros(3) if origin is None else np.asarray(origin, np.float64).reshape(3)
    sph = _ext.spherical_coordinates(points, o, num_threads)
    cache: dict = {}
    for split in ((_RANGE_SPLIT, _ANGLE_SPLIT), _SAFE_SPLIT):
        best = None
        for az_exact in (False, True):
            grid = plan_grid(sph, max_error, o, split, az_exact, cache)
            if grid is None:
                return None
            if az_exact and (best is not None and best[1].az_count == grid.az_count):
                break  # the same grid: the lattice was already exact (or there is none)
            stream, stats = _ext.predictive_encode(points, grid.native(), num_threads)
            worst, checksum, part_bits = stats.max_error_m, stats.checksum, stats.part_bits
            if worst <= max_error and (best is None or len(stream) < len(best[0])):
                best = stream, grid, int(checksum), float(worst), part_bits
            if grid.az_lattice == 0 or not len(grid.el_table):
                break  # no lattice to keep exactly
        if best is not None:
            return best
    return None


def decode_points(stream: bytes, n_points: int, grid: ScanGrid, checksum: int,
                  num_threads: int = 0) -> np.ndarray:
    """(N, 3) float32 [m] points of a stream of :func:`encode_points`, in coding order."""
    from .. import _ext

    return _ext.predictive_decode(stream, n_points, grid.native(), checksum, num_threads)


__all__ = ["CODEC_NAME", "CODEC_NAMES", "ScanGrid", "angle_lattice", "decode_points",
           "elevation_table", "encode_points", "laser_table", "nearest_laser", "plan_grid",
           "range_lattice"]
