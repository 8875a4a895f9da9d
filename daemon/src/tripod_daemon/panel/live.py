# SPDX-License-Identifier: BSD-3-Clause
"""What the panel knows about the daemon, gathered over Zenoh like any other client.

* status (1 Hz publication) and events: small JSON, by callback;
* IMU quaternions: a ring of one sample inside zenoh (no Python call per sample; the latest is
  taken when the page asks);
* lidar packets: only a window of about one rotation every ``image_interval_s``, and only while
  a page is open: the subscriber (on the lidar blocks, ``tripod_shared.lidar_block``) is
  declared for the window and undeclared after it, so the daemon does not even send the other
  ~90 % of the packets to the panel.

:meth:`LiveState.snapshot` turns it into the page's JSON, with the warnings in plain words.
"""

from __future__ import annotations

import base64
import json
import logging
import math
import os
import threading
import time
from collections import deque

from tripod_shared import messages, topics
from tripod_shared.lidar_block import LidarBlockDecoder
from tripod_shared.velodyne import (
    DATA_PACKET_SIZE,
    PRODUCT_ID_OFFSET,
    PRODUCTS,
    RETURN_MODE_OFFSET,
    RETURN_MODES,
)

from ..client import ClientError, ClientOptions, control, open_session
from . import range_image

log = logging.getLogger(__name__)

WINDOW_MAX_S = 0.3  # a window ends after two azimuth wraps or this long [s]
CLIENT_IDLE_S = 5.0  # no page asked for this long: no lidar windows
DISK_WARN_MIN = 15.0  # "disk full in N min" below this
IMU_SILENT_S = 1.0  # "IMU silent for N s" from this


def tilt_deg(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """(tilt, roll, pitch) [deg] of the head from q_world_imu: tilt is the angle between the
    IMU's z axis and the world's vertical; roll about x, pitch about y (ZYX Euler angles)."""
    n = math.sqrt(w * w + x * x + y * y + z * z) or 1.0
    w, x, y, z = w / n, x / n, y / n, z / n
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, 1.0 - 2.0 * (x * x + y * y)))))
    roll = math.degrees(math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)))
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x)))))
    return tilt, roll, pitch


def _minutes(s: float) -> str:
    return f"{s / 60:.0f} min" if s >= 90 else f"{s:.0f} s"


class LiveState:
    """Owns the panel's Zenoh session (reconnected in the background when lost)."""

    def __init__(self, opts: ClientOptions, image_interval_s: float = 1.0):
        self.opts = opts
        self.image_interval_s = image_interval_s
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.session = None
        self._decls: list = []
        self._imu_sub = None
        self.error = ""  # why there is no session
        self.status: dict | None = None
        self.status_mono = 0.0
        self._file_rate: deque = deque(maxlen=30)  # (mono, file_bytes)
        self._drops: deque = deque(maxlen=30)  # (mono, total drops)
        self.marks: list[dict] = []  # marks since the last start event (or panel start)
        self.imu: tuple | None = None  # (w, x, y, z)
        self.imu_mono = 0.0
        self.image_b64 = ""
        self.image_seq = 0
        self.image_mono = 0.0
        self.image_packets = 0
        self.image_empty_pct = 0.0
        self.return_mode = ""
        self.product = ""
        self.client_mono = 0.0
        self._thread = threading.Thread(target=self._run, name="panel-live", daemon=True)

    # ---- session ----------------------------------------------------------------------------
    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self._close_session()

    def _open(self) -> None:
        s = open_session(self.opts)
        dev = self.opts.device_id
        self._decls = [
            s.declare_subscriber(topics.key_status(dev), self._on_status),
            s.declare_subscriber(topics.key_events(dev), self._on_event),
        ]
        import zenoh

        self._imu_sub = s.declare_subscriber(topics.key_imu(dev), zenoh.handlers.RingChannel(1))
        self._decls.append(self._imu_sub)
        self.session = s
        self.error = ""
        log.info("connected to tripod/%s at %s", dev, self.opts.endpoint)

    def _close_session(self) -> None:
        for d in self._decls:
            try:
                d.undeclare()
            except Exception:  # noqa: BLE001
                pass
        self._decls, self._imu_sub = [], None
        if self.session is not None:
            try:
                self.session.close()
            except Exception:  # noqa: BLE001
                pass
            self.session = None

    def _run(self) -> None:
        next_image = 0.0
        while not self._stop.is_set():
            if self.session is None:
                try:
                    self._open()
                except ClientError as exc:
                    if str(exc) != self.error:
                        log.warning("%s (retrying every 2 s)", exc)
                    self.error = str(exc)
                    self._stop.wait(2.0)
                    continue
            now = time.monotonic()
            if now >= next_image:
                next_image = now + self.image_interval_s
                if now - self.client_mono < CLIENT_IDLE_S:
                    try:
                        self._capture_window()
                    except Exception as exc:  # noqa: BLE001 - a picture problem is not fatal
                        log.warning("range image: %s", exc)
            self._stop.wait(max(0.05, next_image - time.monotonic()))

    # ---- callbacks (zenoh threads) ----------------------------------------------------------
    def _on_status(self, sample) -> None:
        try:
            st = json.loads(sample.payload.to_bytes())
        except ValueError:
            return
        now = time.monotonic()
        with self._lock:
            self.status, self.status_mono = st, now
            disk = st.get("disk", {})
            if "file_bytes" in disk:
                self._file_rate.append((now, disk["file_bytes"]))
            else:
                self._file_rate.clear()
            c = st.get("counts", {})
            self._drops.append((now, sum(c.get(k, 0) for k in (
                "lidar_kernel_drops", "record_dropped", "zenoh_dropped"))))

    def _on_event(self, sample) -> None:
        try:
            ev = messages.decode_event(sample.payload.to_bytes())
        except (ValueError, KeyError):
            return
        with self._lock:
            if ev.kind == "start" and ev.label != "sighup":
                self.marks = []
            elif ev.kind == "mark":
                self.marks.append({"n": len(self.marks) + 1, "host_time_ns": ev.host_ns,
                                   "label": ev.label})

    # ---- lidar window -----------------------------------------------------------------------
    def _capture_window(self) -> None:
        got: list[bytes] = []
        done = threading.Event()
        wraps = [0, -1]  # count, previous first-block azimuth

        decoder = LidarBlockDecoder(packet_size=DATA_PACKET_SIZE)

        def on_block(sample) -> None:
            if done.is_set():
                return
            blk = decoder.decode(sample.payload.to_bytes())  # None: a bad block, skipped
            for _ns, p in blk.packets() if blk is not None else ():
                got.append(p)
                az = p[2] | (p[3] << 8)
                if wraps[1] >= 0 and az < wraps[1] - 18000:
                    wraps[0] += 1
                    if wraps[0] >= 2:
                        done.set()
                        return
                wraps[1] = az

        sub = self.session.declare_subscriber(
            topics.key_lidar_blocks(self.opts.device_id), on_block)
        try:
            done.wait(WINDOW_MAX_S)
        finally:
            sub.undeclare()
        done.set()
        if not got:
            return
        pk = range_image.one_rotation(range_image.from_payloads(got))
        img = range_image.range_image(pk)
        grey = range_image.to_grey(img)
        last = got[-1]
        with self._lock:
            self.image_b64 = base64.b64encode(grey.tobytes()).decode("ascii")
            self.image_seq += 1
            self.image_mono = time.monotonic()
            self.image_packets = len(pk)
            self.image_empty_pct = round(100.0 * float((img == 0).mean()), 1)
            self.return_mode = RETURN_MODES.get(last[RETURN_MODE_OFFSET],
                                                f"0x{last[RETURN_MODE_OFFSET]:02x}")
            self.product = PRODUCTS.get(last[PRODUCT_ID_OFFSET],
                                        f"0x{last[PRODUCT_ID_OFFSET]:02x}")

    # ---- actions ----------------------------------------------------------------------------
    def control(self, command: str, label: str = "") -> dict:
        """Run a command on the daemon (blocking); raises ClientError / client.ControlRefused."""
        s = self.session
        if s is None:
            raise ClientError(self.error or "not connected to the daemon")
        return control(s, self.opts, command, label)

    # ---- the page's JSON --------------------------------------------------------------------
    def _imu_latest(self) -> None:
        sub = self._imu_sub
        if sub is None:
            return
        try:
            sample = sub.try_recv()
        except Exception:  # noqa: BLE001
            return
        if sample is None:
            return
        try:
            q = messages.decode_imu(sample.payload.to_bytes())
        except (ValueError, IndexError):
            return
        self.imu, self.imu_mono = (q.w, q.x, q.y, q.z), time.monotonic()

    def snapshot(self, have_image: int = -1) -> dict:
        now = time.monotonic()
        self.client_mono = now
        self._imu_latest()
        with self._lock:
            st = self.status
            age = now - self.status_mono if st is not None else None
            warnings: list[str] = []
            out: dict = {"connected": self.session is not None, "error": self.error,
                         "device_id": self.opts.device_id}
            if self.session is None:
                warnings.append(f"No connection to the daemon: {self.error or 'connecting'}")
            elif st is None:
                warnings.append("Waiting for the daemon's first status")
            elif age > 3.0:
                warnings.append(f"No status from the daemon for {age:.0f} s")
            st = st or {}
            rates, counts = st.get("rates", {}), st.get("counts", {})
            clocks, disk = st.get("clocks", {}), st.get("disk", {})
            # recording
            rec = {"state": st.get("state", "unknown"), "recording": bool(st.get("recording")),
                   "file": os.path.basename(st.get("file") or "") or None,
                   "file_bytes": disk.get("file_bytes"), "free_bytes": disk.get("free_bytes"),
                   "elapsed_s": None, "minutes_left": None}
            if rec["recording"] and disk.get("file_started_ns"):
                rec["elapsed_s"] = max(0, (st.get("host_time_ns", 0)
                                           - disk["file_started_ns"]) // 10**9)
            rate = self._byte_rate() or rates.get("lidar_bytes", 0) * 0.5  # zstd ~2:1
            free = disk.get("free_bytes")
            if free is not None and rate > 0:
                left_s = max(0.0, free - disk.get("min_free_bytes", 0)) / rate
                rec["minutes_left"] = round(left_s / 60, 1)
                if rec["recording"] and left_s < DISK_WARN_MIN * 60:
                    warnings.append(f"Disk full in {_minutes(left_s)}")
            if st and not rec["recording"]:
                warnings.append("Not recording" + (f" ({rec['state']})"
                                                   if rec["state"] != "idle" else ""))
            out["recording"] = rec
            # lidar
            lidar_clock = clocks.get("lidar", {})
            drops = (self._drops[-1][1] if self._drops else 0)
            recent = self._recent_drops(now)
            out["lidar"] = {"rate": rates.get("lidar_data", 0.0),
                            "position_rate": rates.get("lidar_position", 0.0),
                            "drops": drops, "return_mode": self.return_mode or None,
                            "product": self.product or None,
                            "pps": lidar_clock.get("pps", "unknown"),
                            "gps": bool(lidar_clock.get("pps") == "locked")}
            if recent:
                warnings.append(f"{recent} packets lost in the last 10 s")
            if lidar_clock.get("pps") == "error":
                warnings.append("Lidar clock: PPS error")
            # IMU
            imu_present = "imu" in clocks
            imu = {"present": imu_present, "connected": bool(counts.get("imu_connected")),
                   "rate": rates.get("imu_samples", 0.0), "state": "none",
                   "tilt_deg": None, "roll_deg": None, "pitch_deg": None}
            if imu_present:
                silent = now - self.imu_mono if self.imu_mono else None
                if not imu["connected"]:
                    imu["state"] = "disconnected"
                    warnings.append("IMU disconnected")
                elif silent is None or silent >= IMU_SILENT_S:
                    imu["state"] = "stalled"
                    warnings.append("IMU silent" + (f" for {silent:.0f} s" if silent else ""))
                else:
                    imu["state"] = "ok"
                if self.imu is not None and silent is not None and silent < 10:
                    t, r, p = tilt_deg(*self.imu)
                    imu.update(tilt_deg=round(t, 1), roll_deg=round(r, 1), pitch_deg=round(p, 1))
            out["imu"] = imu
            out["marks"] = list(self.marks)
            for m in (st.get("message") or "").split("; "):
                m = m.strip()
                if m and not m.startswith("IMU stalled") and m not in warnings:
                    warnings.append(m[0].upper() + m[1:])
            out["warnings"] = warnings
            img = {"seq": self.image_seq, "rows": 16, "cols": range_image.COLUMNS,
                   "age_s": round(now - self.image_mono, 1) if self.image_mono else None,
                   "packets": self.image_packets, "empty_pct": self.image_empty_pct}
            if self.image_seq != have_image:
                img["grey_b64"] = self.image_b64
            out["image"] = img
            out["status_age_s"] = round(age, 1) if age is not None else None
        return out

    def _byte_rate(self) -> float:
        fr = self._file_rate
        if len(fr) < 3 or fr[-1][0] - fr[0][0] < 2.0 or fr[-1][1] < fr[0][1]:
            return 0.0
        return (fr[-1][1] - fr[0][1]) / (fr[-1][0] - fr[0][0])

    def _recent_drops(self, now: float) -> int:
        old = [d for t, d in self._drops if now - t >= 10.0]
        base = old[-1] if old else (self._drops[0][1] if self._drops else 0)
        return (self._drops[-1][1] - base) if self._drops else 0
