# SPDX-License-Identifier: BSD-3-Clause
"""ASTM E57 files (pye57 / libE57Format): one scan per station, as static scanners deliver them.

Each scan (``/data3D/<k>``) holds its points in the **station frame** (the lidar at the station's
middle time) and the station's pose ``T_map_station`` as the E57 ``pose`` (rotation quaternion
w, x, y, z and translation [m]): readers (CloudCompare, ReCap, Cyclone, pye57's
``read_scan(transform=True)``) place it in the map frame, z up along gravity. Per point:

* ``cartesianX/Y/Z`` [m]: scaled integers, 0.1 mm (quantisation ±0.05 mm);
  ``cartesianInvalidState`` 0 (every point valid).
* ``intensity``: the sensor's 0–255 reflectivity (float32; ``intensityLimits`` 0–255), with
  ``isIntensityInvalid`` = 1 where unknown.
* ``tripod:label``: the segmentation label in an E57 extension (namespace prefix ``tripod``,
  URI :data:`TRIPOD_E57_URI`): 0 ceiling, 1 floor, 2 wall, 3 other, 255 not labelled.
  pye57's high-level ``write_scan_raw`` accepts only the standard fields, so this module builds
  the scan with pye57's libE57Format binding (``pye57.libe57``), which writes extensions;
  readers that do not know the extension skip the field (pye57:
  ``read_scan_raw(i, ignore_unsupported_fields=True)``).

Acquisition start/end are the station's span as E57 ``dateTimeValue`` (GPS seconds).
"""

from __future__ import annotations

import os
import uuid
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

TRIPOD_E57_PREFIX = "tripod"
TRIPOD_E57_URI = "https://github.com/tripod-scanner/tripod/e57/v1"
LABEL_FIELD = f"{TRIPOD_E57_PREFIX}:label"
NO_LABEL = 255
SCALE_M = 1e-4  # [m] per coordinate unit
# GPS time = UNIX time - (1980-01-06 - 1970-01-01) + leap seconds (18 since 2017-01-01)
_GPS_MINUS_UNIX_S = -315_964_800 + 18


@dataclass
class E57Scan:
    """One station as an E57 scan.

    Attributes
    ----------
    name : scan name (``station_000``)
    points : (N, 3) float64 [m], station frame
    T_map_station : (4, 4) float64, the station's pose in the map frame (z up)
    intensity : (N,) float32, 0–255; NaN where unknown
    label : (N,) uint8, segmentation label (:data:`NO_LABEL` where none)
    start_ns, end_ns : station span, lidar time (UNIX ns)
    """

    name: str
    points: np.ndarray
    T_map_station: np.ndarray
    intensity: np.ndarray
    label: np.ndarray
    start_ns: int = 0
    end_ns: int = 0


def unix_ns_to_gps_s(t_ns: int) -> float:
    return t_ns * 1e-9 + _GPS_MINUS_UNIX_S


def write_e57(path: str | os.PathLike, scans: list[E57Scan]) -> None:
    """Write ``scans`` to a new E57 file at ``path`` (replaced if it exists)."""
    import pye57
    from pye57 import libe57

    path = os.fspath(path)
    if os.path.exists(path):
        os.remove(path)  # libE57Format refuses to overwrite
    e57 = pye57.E57(path, mode="w")
    try:
        imf = e57.image_file
        imf.extensionsAdd(TRIPOD_E57_PREFIX, TRIPOD_E57_URI)
        for scan in scans:
            _write_scan(imf, e57.data3d, scan, libe57)
    finally:
        e57.close()


def _write_scan(imf, data3d, scan: E57Scan, libe57) -> None:
    pts = np.ascontiguousarray(np.asarray(scan.points, dtype=np.float64).reshape(-1, 3))
    n = len(pts)
    node = libe57.StructureNode(imf)
    node.set("guid", libe57.StringNode(imf, "{%s}" % uuid.uuid4()))
    node.set("name", libe57.StringNode(imf, scan.name))
    node.set("description", libe57.StringNode(
        imf, "tripod station: points in the station frame, pose = T_map_station (map: z up)"))
    lo = pts.min(axis=0) if n else np.zeros(3)
    hi = pts.max(axis=0) if n else np.zeros(3)
    bounds = libe57.StructureNode(imf)
    for k, ax in enumerate("xyz"):
        bounds.set(f"{ax}Minimum", libe57.FloatNode(imf, float(lo[k])))
        bounds.set(f"{ax}Maximum", libe57.FloatNode(imf, float(hi[k])))
    node.set("cartesianBounds", bounds)
    limits = libe57.StructureNode(imf)
    limits.set("intensityMinimum", libe57.FloatNode(imf, 0.0))
    limits.set("intensityMaximum", libe57.FloatNode(imf, 255.0))
    node.set("intensityLimits", limits)
    # pose: E57 rotation quaternion is w, x, y, z (scipy gives x, y, z, w)
    T = np.asarray(scan.T_map_station, dtype=np.float64)
    qx, qy, qz, qw = Rotation.from_matrix(T[:3, :3]).as_quat()
    pose, rot, tr = (libe57.StructureNode(imf) for _ in range(3))
    for k, v in zip("wxyz", (qw, qx, qy, qz)):
        rot.set(k, libe57.FloatNode(imf, float(v)))
    for k, v in zip("xyz", T[:3, 3]):
        tr.set(k, libe57.FloatNode(imf, float(v)))
    pose.set("rotation", rot)
    pose.set("translation", tr)
    node.set("pose", pose)
    for key, t_ns in (("acquisitionStart", scan.start_ns), ("acquisitionEnd", scan.end_ns)):
        dt = libe57.StructureNode(imf)
        dt.set("dateTimeValue", libe57.FloatNode(imf, unix_ns_to_gps_s(int(t_ns))))
        dt.set("isAtomicClockReferenced", libe57.IntegerNode(imf, 0))
        node.set(key, dt)

    # point record prototype: scaled-integer xyz, float intensity + validity, extension label
    proto = libe57.StructureNode(imf)
    big = 2**31 - 1
    for ax in "XYZ":
        proto.set(f"cartesian{ax}", libe57.ScaledIntegerNode(imf, 0, -big, big, SCALE_M, 0.0))
    proto.set("cartesianInvalidState", libe57.IntegerNode(imf, 0, 0, 2))
    proto.set("intensity", libe57.FloatNode(imf, 0.0, libe57.E57_SINGLE, 0.0, 255.0))
    proto.set("isIntensityInvalid", libe57.IntegerNode(imf, 0, 0, 1))
    proto.set(LABEL_FIELD, libe57.IntegerNode(imf, NO_LABEL, 0, 255))
    points = libe57.CompressedVectorNode(imf, proto, libe57.VectorNode(imf, True))
    node.set("points", points)
    data3d.append(node)

    inten = np.asarray(scan.intensity, dtype=np.float32).reshape(n)
    bad = ~np.isfinite(inten)
    arrays = {
        "cartesianX": pts[:, 0].copy(), "cartesianY": pts[:, 1].copy(),
        "cartesianZ": pts[:, 2].copy(), "cartesianInvalidState": np.zeros(n, np.int8),
        "intensity": np.where(bad, 0.0, np.clip(inten, 0, 255)).astype(np.float32),
        "isIntensityInvalid": bad.astype(np.int8),
        # uint8, not int64: the binding takes numpy int64 ('l') as a 4-byte C long
        LABEL_FIELD: np.asarray(scan.label, dtype=np.uint8).reshape(n),
    }
    bufs = libe57.VectorSourceDestBuffer()
    for name, arr in arrays.items():
        bufs.append(libe57.SourceDestBuffer(imf, name, arr, n, True, True))
    writer = points.writer(bufs)
    if n:
        writer.write(n)
    writer.close()


def read_e57(path: str | os.PathLike) -> list[E57Scan]:
    """Read every scan of an E57 file written by :func:`write_e57` (the label field is optional:
    a scan without it reads as :data:`NO_LABEL`)."""
    import pye57
    from pye57 import libe57

    e57 = pye57.E57(os.fspath(path))
    try:
        out = []
        for i in range(e57.scan_count):
            h = e57.get_header(i)
            raw = e57.read_scan_raw(i, ignore_unsupported_fields=True)
            n = h.point_count
            pts = np.stack([raw["cartesianX"], raw["cartesianY"], raw["cartesianZ"]], axis=1)
            inten = np.asarray(raw.get("intensity", np.full(n, np.nan)), np.float32)
            label = np.full(n, NO_LABEL, np.uint8)
            fields = set(h.point_fields)
            extra = {}
            for name, dtype in (("isIntensityInvalid", np.int8), (LABEL_FIELD, np.uint8)):
                if name in fields:
                    extra[name] = np.empty(n, dtype)
            if extra and n:
                _read_fields(e57.image_file, h.points, extra, n, libe57)
            if "isIntensityInvalid" in extra:
                inten = np.where(extra["isIntensityInvalid"] != 0, np.nan, inten)
            if LABEL_FIELD in extra:
                label = extra[LABEL_FIELD].astype(np.uint8)
            T = np.eye(4)
            qw, qx, qy, qz = (float(v) for v in h.rotation)
            T[:3, :3] = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
            T[:3, 3] = h.translation
            start = _node_time_ns(h.node, "acquisitionStart")
            end = _node_time_ns(h.node, "acquisitionEnd")
            out.append(E57Scan(_node_str(h.node, "name"), pts, T, inten, label, start, end))
        return out
    finally:
        e57.close()


def _read_fields(imf, points, out: dict[str, np.ndarray], n: int, libe57, block: int = 1 << 16
                 ) -> None:
    """Fill ``out`` (name -> (n,) array) from a compressed vector: a read returns as many
    records as it has decoded (not always all), into the buffers from their start."""
    tmp = {name: np.empty(min(n, block), arr.dtype) for name, arr in out.items()}
    bufs = libe57.VectorSourceDestBuffer()
    for name, arr in tmp.items():
        bufs.append(libe57.SourceDestBuffer(imf, name, arr, len(arr), True, True))
    reader = points.reader(bufs)
    try:
        pos = 0
        while pos < n:
            got = reader.read()
            if got == 0:
                raise ValueError(f"E57 scan ends after {pos} of {n} points")
            for name, arr in out.items():
                arr[pos:pos + got] = tmp[name][:got]
            pos += got
    finally:
        reader.close()


def _node_str(node, key: str) -> str:
    return node[key].value() if node.isDefined(key) else ""


def _node_time_ns(node, key: str) -> int:
    if not node.isDefined(key):
        return 0
    return int(round((node[key]["dateTimeValue"].value() - _GPS_MINUS_UNIX_S) * 1e9))
