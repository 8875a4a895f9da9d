# SPDX-License-Identifier: BSD-3-Clause
"""The live view: rotations of a :class:`~.stream.LiveStream` shown through the Foxglove
WebSocket protocol (foxglove-sdk), so Foxglove opens the tripod like a robot.

Channels (Foxglove schemas, protobuf):

=====================  ================  ======================================================
topic                  schema            what
=====================  ================  ======================================================
``/lidar/points``      PointCloud        the current rotation, frame ``lidar``: x, y, z float32
                                         [m], intensity, ring, return_type uint8
``/tf``                FrameTransforms   ``world`` → ``imu`` (the IMU orientation at the
                                         rotation's middle) and ``imu`` → ``lidar`` (the mount)
``/coverage``          PointCloud        every voxel (``voxel_m``) hit so far, placed by the IMU
                                         orientation, frame ``world`` (view it from above), 1 Hz
``/stations/fragment`` PointCloud        each finished station's points, placed, voxelised
                                         (``station_voxel_m``), frame ``world``
``/live/stats``        JSON              counters, median lag, stations, the daemon's status
=====================  ================  ======================================================

Placement is by orientation only: live there is no registration, so every station sits at
the origin of ``world`` (the fragments of different stations overlap; ``tripod reconstruct``
places them). A station is a still period of the head (its pan axis, seen by the IMU, tilts by
less than ``still_tilt_deg`` in ``still_gap_s``, for at least ``min_station_s``; it ends after
``moving_rotations`` moving rotations in a row), cut also at
the daemon's ``mark`` events and when the stream stops.

One rotation is decoded in one call of the native decoder (``decode.native``); all work runs
on the calling thread (one core). Nothing is written to disk.
"""

from __future__ import annotations

import collections
import logging
import time

import numpy as np
from pydantic import Field
from scipy.spatial.transform import Rotation as Rot

from tripod_shared.config_io import StrictModel

from ..decode.native import NativeVlp16Decoder
from .stream import LiveStream, Rotation

log = logging.getLogger(__name__)


class LiveConfig(StrictModel):
    voxel_m: float = Field(default=0.10, gt=0)  #: coverage voxel [m]
    station_voxel_m: float = Field(default=0.05, gt=0)  #: station fragment voxel [m]
    max_voxels: int = Field(default=2_000_000, gt=0)  #: coverage stops growing beyond this
    coverage_period_s: float = Field(default=1.0, gt=0)
    still_tilt_deg: float = Field(default=0.25, gt=0)
    still_gap_s: float = Field(default=0.5, gt=0)
    min_station_s: float = Field(default=1.0, ge=0)
    #: a station ends after this many rotations in a row with the head moving (one alone is
    #: IMU noise or a bump, not the carry)
    moving_rotations: int = Field(default=3, ge=1)
    min_range_m: float = Field(default=0.4, ge=0)
    max_range_m: float = Field(default=100.0, gt=0)
    queue_rotations: int = Field(default=4, ge=1)  #: 0.4 s at 10 Hz
    q_imu_lidar: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)  #: mount, w x y z


# ---- voxel sets -------------------------------------------------------------------------------
_OFF = 1 << 20  # voxel indices in [-2^20, 2^20): ±100 km at 0.1 m


def voxel_keys(xyz: np.ndarray, voxel_m: float) -> np.ndarray:
    """Sorted unique int64 keys of the voxels holding ``xyz`` (N, 3) [m]."""
    idx = np.floor(xyz / voxel_m).astype(np.int64) + _OFF
    idx = np.clip(idx, 0, 2 * _OFF - 1)
    return np.unique((idx[:, 0] << 42) | (idx[:, 1] << 21) | idx[:, 2])


def voxel_centres(keys: np.ndarray, voxel_m: float) -> np.ndarray:
    """(M, 3) float32 centres [m] of voxel keys."""
    mask = (1 << 21) - 1
    idx = np.stack([(keys >> 42) & mask, (keys >> 21) & mask, keys & mask], axis=1) - _OFF
    return ((idx + 0.5) * voxel_m).astype(np.float32)


class VoxelSet:
    """A growing set of voxels (sorted keys), bounded by ``max_voxels``. Each rotation's keys
    wait in a list and are merged when read or when ``merge_keys`` are waiting (one sort a
    second, not one per rotation)."""

    def __init__(self, voxel_m: float, max_voxels: int = 2_000_000, merge_keys: int = 500_000):
        self.voxel_m, self.max_voxels, self.merge_keys = voxel_m, max_voxels, merge_keys
        self.keys = np.zeros(0, np.int64)
        self._pending: list[np.ndarray] = []
        self._n_pending = 0
        self.full = False

    def add(self, xyz: np.ndarray) -> None:
        if not len(xyz) or self.full:
            return
        k = voxel_keys(xyz, self.voxel_m)
        self._pending.append(k)
        self._n_pending += len(k)
        if self._n_pending >= self.merge_keys:
            self._merge()

    def _merge(self) -> None:
        if not self._pending:
            return
        self.keys = np.unique(np.concatenate([self.keys, *self._pending]))
        self._pending, self._n_pending = [], 0
        if len(self.keys) >= self.max_voxels and not self.full:
            self.full = True
            log.warning("voxel map full (%d voxels): it stops growing", len(self.keys))

    def __len__(self) -> int:
        self._merge()
        return len(self.keys)

    def centres(self) -> np.ndarray:
        self._merge()
        return voxel_centres(self.keys, self.voxel_m)


# ---- stations ----------------------------------------------------------------------------------
class StationTracker:
    """Still periods of the head from its orientation alone (the reconstruction's IMU rule):
    the pan axis in the IMU frame is the running mean of the world's up seen by the IMU; the
    head is still while that axis, in the world, tilts by less than ``still_tilt_deg`` over
    ``still_gap_s``."""

    def __init__(self, cfg: LiveConfig):
        self.cfg = cfg
        self._up_sum = np.zeros(3)
        self._hist: collections.deque = collections.deque()  # (t_ns, R_world_imu)

    def still(self, t_ns: int, R_world_imu: np.ndarray) -> bool:
        self._up_sum += R_world_imu.T @ np.array([0.0, 0.0, 1.0])
        b = self._up_sum / np.linalg.norm(self._up_sum)
        self._hist.append((t_ns, R_world_imu))
        gap_ns = int(self.cfg.still_gap_s * 1e9)
        while len(self._hist) > 1 and t_ns - self._hist[1][0] >= gap_ns:
            self._hist.popleft()
        t0, R0 = self._hist[0]
        if t_ns - t0 < gap_ns:
            return True  # not enough history yet: take the start as still
        c = float(np.clip((R_world_imu @ b) @ (R0 @ b), -1.0, 1.0))
        return float(np.degrees(np.arccos(c))) < self.cfg.still_tilt_deg


def _timestamp(t_ns: int):
    from foxglove.messages import Timestamp

    return Timestamp(int(t_ns // 1_000_000_000), int(t_ns % 1_000_000_000))


def _quat(q_wxyz):
    from foxglove.messages import Quaternion

    w, x, y, z = (float(c) for c in q_wxyz)
    return Quaternion(x=x, y=y, z=z, w=w)


class LiveView:
    """Runs the Foxglove server and shows the rotations of ``stream``.

    Parameters
    ----------
    stream : LiveStream
    cfg : LiveConfig
    host, port : str, int
        Where the Foxglove WebSocket server listens (port 0: any free port, see ``port``).
    """

    def __init__(self, stream: LiveStream, cfg: LiveConfig | None = None,
                 host: str = "127.0.0.1", port: int = 8765):
        import foxglove
        from foxglove.channels import FrameTransformsChannel, PointCloudChannel

        self.stream = stream
        self.cfg = cfg = cfg or LiveConfig()
        self.server = foxglove.start_server(name="tripod live", host=host, port=port)
        self.port = self.server.port
        self.ch_points = PointCloudChannel("/lidar/points")
        self.ch_tf = FrameTransformsChannel("/tf")
        self.ch_coverage = PointCloudChannel("/coverage")
        self.ch_station = PointCloudChannel("/stations/fragment")
        self.ch_stats = foxglove.Channel("/live/stats", message_encoding="json")
        self.decoder = NativeVlp16Decoder(min_range_m=cfg.min_range_m,
                                          max_range_m=cfg.max_range_m)
        self.R_imu_lidar = Rot.from_quat(np.r_[cfg.q_imu_lidar[1:], cfg.q_imu_lidar[0]])
        self.coverage = VoxelSet(cfg.voxel_m, cfg.max_voxels)
        self.tracker = StationTracker(cfg)
        self.station: VoxelSet | None = None
        self.station_start_ns = 0
        self._moving = 0  # rotations in a row with the head moving
        self.stations: list[dict] = []
        self.shown = 0
        self.points_shown = 0
        self.lags_ns: collections.deque = collections.deque(maxlen=100_000)
        self.no_imu = 0
        self._last_coverage = 0.0
        self._last_stats = 0.0
        self._last_t_ns = 0

    # -----------------------------------------------------------------------------------------
    def run(self, duration_s: float | None = None, idle_timeout_s: float = 1.0) -> None:
        """Show rotations until ``duration_s`` (None: until interrupted)."""
        end = None if duration_s is None else time.monotonic() + duration_s
        while end is None or time.monotonic() < end:
            rot = self.stream.get_rotation(timeout_s=min(idle_timeout_s, 0.25))
            for ev in self.stream.pop_events():
                if ev.kind in ("mark", "start", "stop"):
                    self._finish_station(f"{ev.kind} {ev.label}".strip())
            if rot is not None:
                self.show(rot)
            elif (self.stream.last_packet_ns
                  and time.time_ns() - self.stream.last_packet_ns > idle_timeout_s * 1e9):
                self._finish_station("stream stopped")
            self._publish_stats()

    def _orientation(self, t_ns: int) -> np.ndarray | None:
        ts, qs = self.stream.imu_track()
        if not len(ts):
            return None
        i = int(np.clip(np.searchsorted(ts, t_ns), 1, len(ts) - 1)) if len(ts) > 1 else 0
        if len(ts) > 1 and abs(ts[i - 1] - t_ns) < abs(ts[i] - t_ns):
            i -= 1
        return qs[i]

    def show(self, rot: Rotation) -> None:
        """Decode one rotation and publish its cloud, transforms, coverage and stations."""
        from foxglove.messages import (FrameTransform, FrameTransforms, PackedElementField,
                                       PackedElementFieldNumericType, PointCloud, Vector3)

        cfg = self.cfg
        batch = self.decoder.decode(rot.packets, rot.host_ns)
        pts = batch.points
        t_first, t_mid = int(rot.host_ns[0]), int(rot.host_ns[len(rot.host_ns) // 2])
        self._last_t_ns = t_mid
        # the current rotation, in the lidar frame, straight from the decoder's layout
        F = PackedElementFieldNumericType
        dt = pts.dtype
        fields = [PackedElementField(name=n, offset=dt.fields[n][1], type=t) for n, t in (
            ("x", F.Float32), ("y", F.Float32), ("z", F.Float32), ("intensity", F.Uint8),
            ("ring", F.Uint8), ("return_type", F.Uint8))]
        self.ch_points.log(PointCloud(timestamp=_timestamp(t_first), frame_id="lidar",
                                      point_stride=dt.itemsize, fields=fields,
                                      data=pts.tobytes()))
        # orientation: world -> imu -> lidar
        q = self._orientation(t_mid)
        if q is None:
            self.no_imu += 1
            q = np.array([1.0, 0.0, 0.0, 0.0])
        R_world_imu = Rot.from_quat(np.r_[q[1:], q[0]])
        qil = cfg.q_imu_lidar
        ts = _timestamp(t_mid)
        self.ch_tf.log(FrameTransforms(transforms=[
            FrameTransform(timestamp=ts, parent_frame_id="world", child_frame_id="imu",
                           translation=Vector3(x=0.0, y=0.0, z=0.0), rotation=_quat(q)),
            FrameTransform(timestamp=ts, parent_frame_id="imu", child_frame_id="lidar",
                           translation=Vector3(x=0.0, y=0.0, z=0.0), rotation=_quat(qil)),
        ]))
        # placed points: coverage, and the station being scanned
        xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1)
        R_world_lidar = (R_world_imu * self.R_imu_lidar).as_matrix().astype(np.float32)
        xyz_w = xyz @ R_world_lidar.T
        self.coverage.add(xyz_w)
        if self.tracker.still(t_mid, R_world_imu.as_matrix()):
            self._moving = 0
            if self.station is None:
                self.station = VoxelSet(cfg.station_voxel_m, cfg.max_voxels)
                self.station_start_ns = t_mid
            self.station.add(xyz_w)
        else:
            self._moving += 1
            if self._moving >= cfg.moving_rotations:
                self._finish_station("head moved")
        self.shown += 1
        self.points_shown += len(pts)
        self.lags_ns.append(time.time_ns() - int(rot.host_ns[-1]))
        now = time.monotonic()
        if now - self._last_coverage >= cfg.coverage_period_s:
            self._publish_cloud(self.ch_coverage, self.coverage, t_mid)
            self._last_coverage = now

    def _publish_cloud(self, channel, voxels: VoxelSet, t_ns: int) -> None:
        from foxglove.messages import PackedElementField, PackedElementFieldNumericType, PointCloud

        F = PackedElementFieldNumericType.Float32
        channel.log(PointCloud(
            timestamp=_timestamp(t_ns), frame_id="world", point_stride=12,
            fields=[PackedElementField(name=n, offset=4 * i, type=F)
                    for i, n in enumerate("xyz")],
            data=voxels.centres().tobytes()))

    def _finish_station(self, why: str) -> None:
        st, self.station = self.station, None
        if st is None:
            return
        dur_s = (self._last_t_ns - self.station_start_ns) * 1e-9
        if dur_s < self.cfg.min_station_s or not len(st):
            return
        self._publish_cloud(self.ch_station, st, self._last_t_ns)
        info = {"station": len(self.stations), "start_ns": self.station_start_ns,
                "duration_s": round(dur_s, 3), "voxels": len(st), "ended_by": why}
        self.stations.append(info)
        log.info("station %d: %.1f s, %d voxels (%s)", info["station"], dur_s, len(st), why)

    def stats(self) -> dict:
        c = self.stream.counts
        lags = np.asarray(self.lags_ns, dtype=np.float64)
        return {
            "packets": c.packets, "packets_missing": c.missing, "malformed": c.malformed,
            "rotations": c.rotations,
            "rotations_shown": self.shown, "rotations_dropped": c.rotations_dropped,
            "points_shown": self.points_shown, "imu_samples": c.imu_samples,
            "rotations_without_imu": self.no_imu,
            "lag_median_s": round(float(np.median(lags)) * 1e-9, 4) if len(lags) else None,
            "lag_p95_s": round(float(np.percentile(lags, 95)) * 1e-9, 4) if len(lags) else None,
            "coverage_voxels": len(self.coverage), "stations": list(self.stations),
            "daemon_status": self.stream.status,
        }

    def _publish_stats(self) -> None:
        now = time.monotonic()
        if now - self._last_stats >= 1.0:
            self.ch_stats.log(self.stats())
            self._last_stats = now

    def close(self) -> None:
        self._finish_station("live view closed")
        try:
            self.server.stop()
        except Exception:  # noqa: BLE001
            pass
