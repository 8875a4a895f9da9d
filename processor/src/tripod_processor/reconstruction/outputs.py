# SPDX-License-Identifier: BSD-3-Clause
"""Writers of the reconstruction's outputs: TUM trajectories, clouds, and a Foxglove MCAP.

TUM lines are ``timestamp tx ty tz qx qy qz qw`` with the timestamp in lidar time, UNIX seconds
(9 decimals), the pose T_map_lidar (map frame: z up along gravity).
"""

from __future__ import annotations

import base64
import json
import os
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation


def write_tum(path: str | os.PathLike, t_ns: np.ndarray, T: np.ndarray,
              header: str | None = None) -> None:
    """Write poses (N, 4, 4) at lidar times t_ns (N,) int64 as a TUM trajectory."""
    q = Rotation.from_matrix(np.asarray(T)[:, :3, :3]).as_quat()  # x, y, z, w
    with open(path, "w", encoding="utf-8") as fh:
        if header:
            for ln in header.splitlines():
                fh.write(f"# {ln}\n")
        for t, M, qq in zip(t_ns, T, q):
            sec, nsec = divmod(int(t), 1_000_000_000)
            x, y, z = M[:3, 3]
            fh.write(f"{sec}.{nsec:09d} {x:.6f} {y:.6f} {z:.6f} "
                     f"{qq[0]:.9f} {qq[1]:.9f} {qq[2]:.9f} {qq[3]:.9f}\n")


def read_tum(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM file → (t_ns (N,) int64, T (N, 4, 4))."""
    ts, Ts = [], []
    with open(path, encoding="utf-8") as fh:
        for ln in fh:
            ln = ln.strip()
            if not ln or ln.startswith("#"):
                continue
            f = ln.split()
            sec, _, frac = f[0].partition(".")
            ts.append(int(sec) * 1_000_000_000 + int((frac + "000000000")[:9]))
            T = np.eye(4)
            T[:3, 3] = [float(v) for v in f[1:4]]
            T[:3, :3] = Rotation.from_quat([float(v) for v in f[4:8]]).as_matrix()
            Ts.append(T)
    return np.asarray(ts, dtype=np.int64), np.asarray(Ts).reshape(-1, 4, 4)


# ---- Foxglove MCAP ------------------------------------------------------------------------------
POINTCLOUD_SCHEMA = {
    "title": "foxglove.PointCloud",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"},
                                                       "nsec": {"type": "integer"}}},
        "frame_id": {"type": "string"},
        "pose": {"type": "object", "properties": {
            "position": {"type": "object", "properties": {
                "x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}}},
            "orientation": {"type": "object", "properties": {
                "x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"},
                "w": {"type": "number"}}}}},
        "point_stride": {"type": "integer"},
        "fields": {"type": "array", "items": {"type": "object", "properties": {
            "name": {"type": "string"}, "offset": {"type": "integer"},
            "type": {"type": "integer"}}}},
        "data": {"type": "string", "contentEncoding": "base64"},
    },
}
FRAMETRANSFORM_SCHEMA = {
    "title": "foxglove.FrameTransform",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"},
                                                       "nsec": {"type": "integer"}}},
        "parent_frame_id": {"type": "string"},
        "child_frame_id": {"type": "string"},
        "translation": {"type": "object", "properties": {
            "x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}}},
        "rotation": {"type": "object", "properties": {
            "x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"},
            "w": {"type": "number"}}},
    },
}
FLOAT32 = 7


def _stamp(t_ns: int) -> dict:
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def pointcloud_message(points: np.ndarray, t_ns: int, frame_id: str,
                       intensity: np.ndarray | None = None) -> dict:
    """foxglove.PointCloud (JSON encoding) of (N, 3) points [m] in ``frame_id``."""
    cols = [np.asarray(points, dtype="<f4")[:, :3]]
    fields = [{"name": n, "offset": 4 * k, "type": FLOAT32} for k, n in enumerate("xyz")]
    if intensity is not None:
        cols.append(np.asarray(intensity, dtype="<f4").reshape(-1, 1))
        fields.append({"name": "intensity", "offset": 12, "type": FLOAT32})
    data = np.ascontiguousarray(np.hstack(cols)).tobytes()
    return {
        "timestamp": _stamp(t_ns), "frame_id": frame_id,
        "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                 "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
        "point_stride": 4 * len(fields), "fields": fields,
        "data": base64.b64encode(data).decode("ascii"),
    }


def frame_transform_message(T: np.ndarray, t_ns: int, parent: str, child: str,
                            q_xyzw: np.ndarray | None = None) -> dict:
    """A foxglove.FrameTransform of T (4, 4); ``q_xyzw``: its rotation's quaternion when
    already computed (a batch of them at once is far cheaper)."""
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat() if q_xyzw is None else q_xyzw
    return {
        "timestamp": _stamp(t_ns), "parent_frame_id": parent, "child_frame_id": child,
        "translation": {"x": float(T[0, 3]), "y": float(T[1, 3]), "z": float(T[2, 3])},
        "rotation": {"x": float(x), "y": float(y), "z": float(z), "w": float(w)},
    }


def write_foxglove_mcap(path: str | os.PathLike, map_points: np.ndarray, map_t_ns: int,
                        station_t_ns: list[int], T_map_station: np.ndarray,
                        fragments: list[np.ndarray], trajectory: tuple[np.ndarray, np.ndarray]
                        ) -> None:
    """An MCAP that Foxglove opens: /map (foxglove.PointCloud in frame ``map``), one
    /tf FrameTransform map→station_k per station plus map→lidar along the trajectory, and each
    fragment on /fragments in its own station frame."""
    from mcap.writer import Writer

    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="", library="tripod reconstruct")
        pc = w.register_schema("foxglove.PointCloud", "jsonschema",
                               json.dumps(POINTCLOUD_SCHEMA).encode())
        tf = w.register_schema("foxglove.FrameTransform", "jsonschema",
                               json.dumps(FRAMETRANSFORM_SCHEMA).encode())
        ch_map = w.register_channel("/map", "json", pc)
        ch_frag = w.register_channel("/fragments", "json", pc)
        ch_tf = w.register_channel("/tf", "json", tf)
        msgs = []
        for k, (t, T) in enumerate(zip(station_t_ns, T_map_station)):
            msgs.append((int(t), ch_tf, frame_transform_message(T, t, "map", f"station_{k}")))
            if k < len(fragments) and len(fragments[k]):
                msgs.append((int(t), ch_frag, pointcloud_message(fragments[k], t, f"station_{k}")))
        traj_t, traj_T = trajectory
        traj_q = (Rotation.from_matrix(np.asarray(traj_T)[:, :3, :3]).as_quat()
                  if len(traj_T) else np.zeros((0, 4)))
        for t, T, q in zip(traj_t, traj_T, traj_q):
            msgs.append((int(t), ch_tf, frame_transform_message(T, t, "map", "lidar", q)))
        msgs.append((int(map_t_ns), ch_map, pointcloud_message(map_points, map_t_ns, "map")))
        msgs.sort(key=lambda m: m[0])
        for seq, (t, ch, body) in enumerate(msgs):
            w.add_message(ch, t, json.dumps(body).encode(), t, seq)
        w.finish()


def write_json(path: str | os.PathLike, data: dict) -> None:
    Path(path).write_text(json.dumps(data, indent=2, default=float) + "\n", encoding="utf-8")
