# SPDX-License-Identifier: BSD-3-Clause
"""Zenoh live path: publishers on the key expressions of ``tripod_shared.topics``, the status and
control queryables, and a publishing thread behind a bounded queue.

The receive loop never waits on the network: it hands batches to :meth:`LivePublisher.submit`,
which drops (and counts in ``zenoh_dropped``) whatever does not fit in ``queue_messages``.
With ``congestion_control: drop`` (default) each subscriber's link has its own queue in zenoh:
a slow subscriber loses its own data (zenoh drops for that link only; the subscriber sees the
gap in the packets' stamps) and never holds up another subscriber or the recording. ``block``
makes the publishing thread wait for the slowest subscriber: every subscriber then gets only
what the slowest takes, and our queue's overflow is counted.
Payloads are the very bytes recorded to MCAP (CDR, or JSON for status and events), except the
live lidar stream: its data packets go out in blocks (``lidar/blocks``, layout in
``tripod_shared.lidar_block``) of at most ``lidar_block_bytes``, so a subscriber pays per block,
not per packet (a Python subscriber spends 3-5 µs per sample: 16-23 % of a core at 50,000
packets/s, before doing anything with the data). Each block carries the number of its first
packet among all the data packets this live path was given (those dropped at our queue
included), so a subscriber counts exactly what it lost. The per-packet key (``lidar/packets``,
one CDR message per sample) is published only while zenoh reports a subscriber matching it: no
cost when nobody wants it.

Security (see the README's security section): the session is built with the config's TLS
(mutual when ``tls.client_ca`` is set) and user/password authentication, and with zenoh access
control generated here: everyone who may connect can subscribe to the data keys and query the
status, but ``control/*`` queries reach the daemon only from the subjects ``zenoh.control``
names (loopback, logins, client-certificate common names). Refused queries never get here
(zenoh drops them). What does get here is checked again: label size and text, and a token
bucket on the command rate; refusals are answered with the reason and counted
(``control_refused_<reason>``); every request is logged with what zenoh tells about the peer.
"""

from __future__ import annotations

import gc
import json
import logging
import queue
import threading
import time
from collections.abc import Callable

import numpy as np
import zenoh

from tripod_shared import topics
from tripod_shared.lidar_block import encode_block, max_packets_for
from tripod_shared.mcap_writer import MESSAGE_HEADER_SIZE, MessageBlock
from tripod_shared.messages import PACKET_PAYLOAD_OFFSET
from tripod_shared.velodyne import DATA_PACKET_SIZE

from .config import ZenohConfig
from .osutil import set_thread_name
from .stats import Counters

log = logging.getLogger(__name__)

Item = tuple[str, int, bytes]
_STOP = object()


_ALL_MESSAGES = ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                 "liveliness_token", "liveliness_query", "declare_liveliness_subscriber"]


def control_subjects(cfg: ZenohConfig) -> list[dict]:
    """Zenoh ACL subjects allowed to query ``control/*`` (empty: nobody)."""
    c = cfg.control
    subjects = []
    if c.allow_loopback:
        subjects.append({"id": "loopback", "interfaces": ["lo"]})
    if c.users:
        subjects.append({"id": "control-users", "usernames": list(c.users)})
    if c.cert_common_names:
        subjects.append({"id": "control-certs", "cert_common_names": list(c.cert_common_names)})
    return subjects


def access_control(cfg: ZenohConfig, device_id: str) -> dict:
    """The zenoh ``access_control`` section: data keys for every connected peer, control for
    :func:`control_subjects` only, everything else denied."""
    everything = topics.key_control(device_id, "**").replace("/control/**", "/**")
    control_key = topics.key_control(device_id, "**")
    subjects = [{"id": "everyone"}]
    policies = [{"id": "data", "rules": ["data", "status"], "subjects": ["everyone"]}]
    ctl = control_subjects(cfg)
    if ctl:
        subjects += ctl
        policies.append({"id": "control", "rules": ["control"],
                         "subjects": [s["id"] for s in ctl]})
    query = ["query", "reply", "declare_queryable"]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [
            # subscribing (also to tripod/<id>/**) and receiving the publications
            {"id": "data", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": [m for m in _ALL_MESSAGES if m not in query], "key_exprs": [everything]},
            {"id": "status", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": query, "key_exprs": [topics.key_status(device_id)]},
            {"id": "control", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": query, "key_exprs": [control_key]},
        ],
        "subjects": subjects,
        "policies": policies,
    }


def build_zenoh_config(cfg: ZenohConfig, device_id: str | None = None) -> zenoh.Config:
    """A zenoh Config: ``config_file`` (if any) with mode, endpoints, scouting, TLS and
    user/password authentication on top; with ``device_id`` (the daemon's own session) also the
    access control of :func:`access_control`. Subscribers and control clients build theirs with
    the same function and their own ``tls``/``auth`` sections."""
    conf = zenoh.Config.from_file(cfg.config_file) if cfg.config_file else zenoh.Config()
    conf.insert_json5("mode", json.dumps(cfg.mode))
    if cfg.listen:
        conf.insert_json5("listen/endpoints", json.dumps(cfg.listen))
    if cfg.connect:
        conf.insert_json5("connect/endpoints", json.dumps(cfg.connect))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(cfg.multicast_scouting))
    conf.insert_json5("transport/link/tx/queue/size/data", json.dumps(cfg.tx_queue_batches))
    # a query payload is a short label: refuse huge messages before they are reassembled
    conf.insert_json5("transport/link/rx/max_message_size", json.dumps(cfg.max_message_bytes))
    tls = cfg.tls
    if tls.certificate:
        for k in ("listen", "connect"):
            conf.insert_json5(f"transport/link/tls/{k}_certificate", json.dumps(tls.certificate))
            conf.insert_json5(f"transport/link/tls/{k}_private_key", json.dumps(tls.private_key))
    if tls.client_ca:
        conf.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(tls.client_ca))
        conf.insert_json5("transport/link/tls/enable_mtls", "true")
    conf.insert_json5("transport/link/tls/verify_name_on_connect",
                      json.dumps(tls.verify_name_on_connect))
    auth = cfg.auth
    usrpwd: dict = {}
    if auth.users_file:
        usrpwd["dictionary_file"] = auth.users_file
    if auth.user:
        with open(auth.password_file, encoding="utf-8") as fh:
            usrpwd.update(user=auth.user, password=fh.read().strip())
    if usrpwd:
        conf.insert_json5("transport/auth/usrpwd", json.dumps(usrpwd))
    if device_id is not None:
        conf.insert_json5("access_control", json.dumps(access_control(cfg, device_id)))
    return conf


class _TokenBucket:
    """``rate`` per second sustained, ``burst`` back to back (host_monotonic)."""

    def __init__(self, rate: float, burst: int):
        self.rate, self.burst = rate, burst
        self.tokens = float(burst)
        self.t = time.monotonic()
        self.lock = threading.Lock()

    def take(self) -> bool:
        with self.lock:
            now = time.monotonic()
            self.tokens = min(self.burst, self.tokens + (now - self.t) * self.rate)
            self.t = now
            if self.tokens >= 1.0:
                self.tokens -= 1.0
                return True
            return False


class ControlRefused(Exception):
    """A control request refused: ``reason`` is the counter suffix, the message the reply."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


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
        for k in ("zenoh_published", "zenoh_dropped", "zenoh_errors", "zenoh_queries",
                  "zenoh_lidar_blocks", "zenoh_lidar_packets", "zenoh_lidar_per_packet",
                  "control_requests", "control_refused", "control_refused_label",
                  "control_refused_rate", "control_refused_command"):
            counts.setdefault(k, 0)
        self._status_reply = status_reply
        self._control = control
        self._bucket = _TokenBucket(cfg.control.rate_per_s, cfg.control.burst)
        self.session = zenoh.open(build_zenoh_config(cfg, device_id))
        cdr, js = zenoh.Encoding.APPLICATION_CDR, zenoh.Encoding.APPLICATION_JSON
        # "drop" (default): zenoh drops per link, so a slow subscriber loses its own samples and
        # no other's; "block": this thread waits for the slowest subscriber, our bounded queue
        # overflows and every dropped message is counted (zenoh_dropped). Either way only this
        # thread waits, never reception or recording.
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
        self._blocks_pub = None
        if cfg.publish_lidar:
            self._blocks_pub = decl(topics.key_lidar_blocks(device_id), encoding=zenoh.Encoding(
                "application/x-tripod-lidar-block"), congestion_control=drop)
        else:
            del self._pubs[topics.TOPIC_LIDAR_PACKETS]
        self._block_packets = max_packets_for(cfg.lidar_block_bytes, DATA_PACKET_SIZE)
        self._lidar_index = 0  # number of the next data packet given to the live path
        self._skipped = 0  # data packets dropped at submit since the last queued batch
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
        who = [s["id"] for s in control_subjects(cfg)]
        if not who:
            log.warning("control refused to everyone: set zenoh.control (allow_loopback, users, "
                        "cert_common_names) to allow it")
        elif who == ["loopback"]:
            log.info("control accepted only from this machine (loopback); to control over the "
                     "network configure zenoh.auth/zenoh.tls and zenoh.control.users or "
                     "cert_common_names (README: security)")
        else:
            log.info("control accepted from: %s", ", ".join(who))

    def submit(self, batch: list[Item]) -> None:
        """Queue a batch for publishing; never blocks, drops (counted) when full."""
        if not batch:
            return
        n = sum([len(it) if isinstance(it, MessageBlock) else 1 for it in batch])
        if self._enqueued - self._dequeued + n > self.cfg.queue_messages:
            self.counts["zenoh_dropped"] += n
            # the dropped data packets still get their numbers: subscribers see the gap
            lidar = topics.TOPIC_LIDAR_PACKETS
            self._skipped += sum([len(it) if isinstance(it, MessageBlock) else 1
                                  for it in batch if (it.topic if isinstance(it, MessageBlock)
                                                      else it[0]) == lidar])
            return
        self._enqueued += n
        self._q.put((batch, self._skipped))
        self._skipped = 0

    def _put(self, pub, data) -> bool:
        try:
            pub.put(data)
            return True
        except Exception as exc:  # noqa: BLE001 - zenoh raises ZError; never fatal
            self.counts["zenoh_errors"] += 1
            log.debug("zenoh put failed: %s", exc)
            return False

    def _matched(self, pub) -> bool:
        """Does a subscriber match ``pub``? (Yes when zenoh cannot tell: publish.)"""
        try:
            return bool(pub.matching_status.matching)
        except Exception:  # noqa: BLE001 - never let the live path die on a status query
            self.counts["zenoh_errors"] += 1
            return True

    def _run(self) -> None:
        set_thread_name("tripod-publish")
        pubs = self._pubs
        counts = self.counts
        lidar = topics.TOPIC_LIDAR_PACKETS
        put = self._put
        while True:
            got = self._q.get()
            if got is _STOP:
                return
            batch, skipped = got
            self._lidar_index += skipped
            n = 0
            # the per-packet key only while someone subscribes to it (zenoh knows)
            per_packet = pubs.get(lidar)
            if per_packet is not None and not self._matched(per_packet):
                per_packet = None
            singles: list = []  # per-item lidar packets (the recvmsg path), one block at the end
            blocks = self._blocks_pub is not None
            for it in batch:
                if isinstance(it, MessageBlock):
                    self._dequeued += len(it)
                    if it.topic == lidar:
                        if blocks:
                            self._publish_rows(it)
                            n += len(it)
                        datas = it.datas() if per_packet is not None else ()
                        pub = per_packet
                    else:
                        pub = pubs.get(it.topic)
                        datas = it.datas() if pub is not None else ()
                else:
                    self._dequeued += 1
                    if it[0] == lidar:
                        singles.append(it)
                        pub = per_packet
                    else:
                        pub = pubs.get(it[0])
                    datas = (it[2],) if pub is not None else ()
                # a lidar packet counts once (published in a block, and maybe on its own too)
                count_puts = pub is not per_packet or not blocks
                for data in datas:
                    if put(pub, data):
                        if count_puts:
                            n += 1
                        if pub is per_packet:
                            counts["zenoh_lidar_per_packet"] += 1
            if singles and blocks:
                self._publish_items(singles)
                n += len(singles)
            counts["zenoh_published"] += n

    def _publish_rows(self, mb: MessageBlock) -> None:
        """A recorder block of data packets as lidar blocks of at most ``_block_packets``."""
        payloads = mb.rows[:, MESSAGE_HEADER_SIZE + PACKET_PAYLOAD_OFFSET:]
        stamps = mb.log_times.view(np.int64)
        self._publish_arrays(stamps, payloads)

    def _publish_items(self, items: list[Item]) -> None:
        payloads = np.frombuffer(b"".join([it[2][PACKET_PAYLOAD_OFFSET:] for it in items]),
                                 np.uint8).reshape(len(items), -1)
        self._publish_arrays(np.array([it[1] for it in items], np.int64), payloads)

    def _publish_arrays(self, stamps: np.ndarray, payloads: np.ndarray) -> None:
        step = self._block_packets
        total = stamps.shape[0]
        for a in range(0, total, step):
            b = min(total, a + step)
            data = encode_block(self._lidar_index + a, stamps[a:b], payloads[a:b])
            if self._put(self._blocks_pub, data):
                self.counts["zenoh_lidar_blocks"] += 1
                self.counts["zenoh_lidar_packets"] += b - a
        self._lidar_index += total

    # ---- queryables (run on zenoh's threads) ------------------------------------------------
    def _on_status_query(self, query) -> None:
        self.counts["zenoh_queries"] += 1
        try:
            query.reply(topics.key_status(self._device_id), self._status_reply(),
                        encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception as exc:  # noqa: BLE001
            log.warning("status query failed: %s", exc)

    def _peer(self, query) -> str:
        """What zenoh tells about the querier: its zid (when the query carries its source) and
        the address, interface and authenticated identity of the link(s) it came over."""
        zid = None
        try:
            si = query.source_info
            if si is not None:
                zid = str(si.source_id.zid)
        except Exception:  # noqa: BLE001 - an unstable API: never let logging refuse a query
            pass
        try:
            links = self.session.info.links()
        except Exception:  # noqa: BLE001
            links = []
        desc = []
        for ln in links:
            if zid is not None and str(ln.zid) != zid:
                continue
            ident = f"{ln.dst} via {','.join(ln.interfaces) or '?'}"
            if ln.auth_identifier:
                ident += f" as {ln.auth_identifier}"
            desc.append(f"zid {ln.zid} at {ident}")
        if not desc:
            return f"zid {zid}" if zid else "an unidentified peer"
        if zid is None and len(desc) > 1:
            return "one of: " + "; ".join(desc)
        return "; ".join(desc)

    def _check_label(self, query) -> str:
        limit = self.cfg.control.max_label_bytes
        raw = query.parameters.get("label") or ""
        if isinstance(raw, str):
            raw = raw.encode("utf-8", "surrogateescape")
        if not raw and query.payload is not None:
            if len(query.payload) > limit:
                raise ControlRefused(
                    "label", f"label too long: {len(query.payload)} bytes > {limit}")
            raw = query.payload.to_bytes()
        if len(raw) > limit:
            raise ControlRefused("label", f"label too long: {len(raw)} bytes > {limit}")
        try:
            label = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise ControlRefused("label", "label is not UTF-8 text") from None
        if any(ord(ch) < 0x20 or ord(ch) == 0x7F for ch in label):
            raise ControlRefused("label", "label contains control characters")
        return label

    def _on_control_query(self, query) -> None:
        with query:  # finished (the final reply sent) on leaving, whoever keeps a reference
            self._control_query(query)

    def _control_query(self, query) -> None:
        c = self.counts
        c["zenoh_queries"] += 1
        c["control_requests"] += 1
        key = str(query.key_expr)
        command = key.rsplit("/", 1)[-1]
        peer = self._peer(query)
        try:
            if command not in topics.CONTROL_COMMANDS:
                raise ControlRefused("command", f"unknown command {command!r} (start, stop, mark)")
            label = self._check_label(query)
            if not self._bucket.take():
                raise ControlRefused(
                    "rate", f"too many control requests (over {self.cfg.control.burst} at once "
                    f"or {self.cfg.control.rate_per_s:g}/s); try again later")
            log.info("control/%s%s from %s", command, f" {label!r}" if label else "", peer)
            result = self._control(command, label)
            query.reply(topics.key_control(self._device_id, command),
                        json.dumps(result).encode(), encoding=zenoh.Encoding.APPLICATION_JSON)
        except ControlRefused as exc:
            c["control_refused"] += 1
            c["control_refused_" + exc.reason] += 1
            # log the text, not the exception: a handler keeping the record would keep its
            # traceback, the frame and the query alive, and zenoh finishes a query (the
            # querier's get returns) only when the query object is dropped
            log.warning("control/%s from %s refused: %s", command[:32], peer, str(exc))
            self._reply_err(query, str(exc))
        except Exception as exc:  # noqa: BLE001 - bad queries get an error reply, nothing else
            self._reply_err(query, str(exc))

    @staticmethod
    def _reply_err(query, message: str) -> None:
        try:
            query.reply_err(json.dumps({"ok": False, "error": message}).encode())
        except Exception as exc:  # noqa: BLE001 - the querier gets zenoh's timeout instead
            log.warning("error reply failed: %s", exc)

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
        for p in [*self._pubs.values(), self._blocks_pub]:
            if p is None:
                continue
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
        self._blocks_pub = None
        self.session = None
        self._status_reply = self._control = None
        gc.collect()
