# SPDX-License-Identifier: BSD-3-Clause
"""Zenoh live path: publishers on the key expressions of ``tripod_shared.topics``, the status and
control queryables, and a publishing thread behind a bounded queue.

The receive loop never waits on the network: it hands batches to :meth:`LivePublisher.submit`,
which drops (and counts in ``zenoh_dropped``) whatever does not fit in ``queue_messages``.
With ``congestion_control: block`` (default) a slow subscriber makes zenoh wait, the queue fills
and the overflow is counted exactly; with ``drop`` zenoh drops silently instead.
Payloads are the very bytes recorded to MCAP (CDR, or JSON for status and events).
"""

from __future__ import annotations

import gc
import json
import logging
import queue
import threading
from collections.abc import Callable

import zenoh

from tripod_shared import topics

from .config import ZenohConfig
from .stats import Counters

log = logging.getLogger(__name__)

Item = tuple[str, int, bytes]
_STOP = object()


def build_zenoh_config(cfg: ZenohConfig) -> zenoh.Config:
    """A zenoh Config: ``config_file`` (if any) with mode, endpoints and scouting on top."""
    conf = zenoh.Config.from_file(cfg.config_file) if cfg.config_file else zenoh.Config()
    conf.insert_json5("mode", json.dumps(cfg.mode))
    if cfg.listen:
        conf.insert_json5("listen/endpoints", json.dumps(cfg.listen))
    if cfg.connect:
        conf.insert_json5("connect/endpoints", json.dumps(cfg.connect))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(cfg.multicast_scouting))
    return conf


class LivePublisher:
    """Owns the zenoh session.

    Parameters
    ----------
    status_reply : callable() -> bytes
        JSON status for the ``status`` queryable.
    control : callable(command, label) -> dict
        Runs ``start``/``stop``/``mark``; the dict is the JSON reply.
    """

    def __init__(
        self,
        cfg: ZenohConfig,
        device_id: str,
        counts: Counters,
        status_reply: Callable[[], bytes],
        control: Callable[[str, str], dict],
    ):
        self.cfg = cfg
        self.counts = counts
        for k in ("zenoh_published", "zenoh_dropped", "zenoh_errors", "zenoh_queries"):
            counts.setdefault(k, 0)
        self._status_reply = status_reply
        self._control = control
        self.session = zenoh.open(build_zenoh_config(cfg))
        cdr, js = zenoh.Encoding.APPLICATION_CDR, zenoh.Encoding.APPLICATION_JSON
        # "block": a slow subscriber backs up into *our* bounded queue, where every dropped
        # message is counted (zenoh_dropped); "drop": zenoh drops inside its own queues, which
        # no counter sees. Either way only this thread waits, never reception or recording.
        drop = (zenoh.CongestionControl.BLOCK if cfg.congestion_control == "block"
                else zenoh.CongestionControl.DROP)
        decl = self.session.declare_publisher
        self._pubs = {
            topics.TOPIC_LIDAR_PACKETS: decl(
                topics.key_lidar_packets(device_id), encoding=cdr, congestion_control=drop),
            topics.TOPIC_LIDAR_POSITION: decl(
                topics.key_lidar_position(device_id), encoding=cdr, congestion_control=drop),
            topics.TOPIC_IMU: decl(topics.key_imu(device_id), encoding=cdr, congestion_control=drop),
            topics.TOPIC_STATUS: decl(
                topics.key_status(device_id), encoding=js,
                congestion_control=zenoh.CongestionControl.DROP),
            topics.TOPIC_EVENTS: decl(
                topics.key_events(device_id), encoding=js,
                congestion_control=zenoh.CongestionControl.BLOCK),
        }
        if not cfg.publish_lidar:
            del self._pubs[topics.TOPIC_LIDAR_PACKETS]
        self._device_id = device_id
        self._queryables = [
            self.session.declare_queryable(topics.key_status(device_id), self._on_status_query),
            self.session.declare_queryable(topics.key_control(device_id, "*"),
                                           self._on_control_query),
        ]
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._enqueued = 0
        self._dequeued = 0
        self._thread = threading.Thread(target=self._run, name="zenoh-publisher", daemon=True)
        self._thread.start()
        log.info("zenoh %s session %s on tripod/%s/**", cfg.mode, self.session.zid(), device_id)

    def submit(self, batch: list[Item]) -> None:
        """Queue a batch for publishing; never blocks, drops (counted) when full."""
        if not batch:
            return
        n = len(batch)
        if self._enqueued - self._dequeued + n > self.cfg.queue_messages:
            self.counts["zenoh_dropped"] += n
            return
        self._enqueued += n
        self._q.put(batch)

    def _run(self) -> None:
        pubs = self._pubs
        counts = self.counts
        while True:
            batch = self._q.get()
            if batch is _STOP:
                return
            self._dequeued += len(batch)
            n = 0
            for topic, _ns, data in batch:
                pub = pubs.get(topic)
                if pub is None:
                    continue
                try:
                    pub.put(data)
                    n += 1
                except Exception as exc:  # noqa: BLE001 - zenoh raises ZError; never fatal
                    counts["zenoh_errors"] += 1
                    log.debug("zenoh put failed: %s", exc)
            counts["zenoh_published"] += n

    # ---- queryables (run on zenoh's threads) ------------------------------------------------
    def _on_status_query(self, query) -> None:
        self.counts["zenoh_queries"] += 1
        try:
            query.reply(topics.key_status(self._device_id), self._status_reply(),
                        encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception as exc:  # noqa: BLE001
            log.warning("status query failed: %s", exc)

    def _on_control_query(self, query) -> None:
        self.counts["zenoh_queries"] += 1
        key = str(query.key_expr)
        command = key.rsplit("/", 1)[-1]
        label = query.parameters.get("label") or ""
        if not label and query.payload is not None:
            label = query.payload.to_bytes().decode("utf-8", "replace")
        try:
            if command not in topics.CONTROL_COMMANDS:
                raise ValueError(f"unknown command {command!r} (start, stop, mark)")
            result = self._control(command, label)
            query.reply(topics.key_control(self._device_id, command),
                        json.dumps(result).encode(), encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception as exc:  # noqa: BLE001 - bad queries get an error reply, nothing else
            try:
                query.reply_err(json.dumps({"ok": False, "error": str(exc)}).encode())
            except Exception:  # noqa: BLE001
                pass

    def close(self) -> None:
        """Stop the thread, undeclare everything and close the session, then drop every zenoh
        object now: a zenoh object (holding our Python callbacks) left for the interpreter's
        final clean-up can be dropped from a Rust thread after Python stopped, which aborts."""
        self._q.put(_STOP)
        self._thread.join(5)
        if self._thread.is_alive():
            log.warning("zenoh publisher thread still busy; closing the session under it")
        for q in self._queryables:
            try:
                q.undeclare()
            except Exception:  # noqa: BLE001
                pass
        for p in self._pubs.values():
            try:
                p.undeclare()
            except Exception:  # noqa: BLE001
                pass
        try:
            self.session.close()
        except Exception:  # noqa: BLE001
            pass
        self._queryables.clear()
        self._pubs = {}
        self.session = None
        self._status_reply = self._control = None
        gc.collect()
