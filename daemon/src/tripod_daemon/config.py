# SPDX-License-Identifier: BSD-3-Clause
"""The daemon's typed config (one pydantic model per component) and where it is searched.

Defaults here and the commented ``default_config.yaml`` shipped in the package (copied to
``deploy/etc/daemon.yaml``) must say the same thing; a test checks it. Files are layered:
``/etc/tripod/daemon.yaml`` (when present) < ``--config FILE`` < command-line flags.
"""

from __future__ import annotations

import ipaddress
import os
import re
from importlib import resources
from typing import Literal

from pydantic import Field, StrictBool, field_validator, model_validator

from tripod_shared import topics
from tripod_shared.config_io import ConfigError, StrictModel, load_layered_config
from tripod_shared.velodyne import DATA_PORT, POSITION_PORT, PRODUCT_HDL32E, PRODUCT_VLP16

SYSTEM_CONFIG = "/etc/tripod/daemon.yaml"

__all__ = [
    "SYSTEM_CONFIG",
    "ConfigError",
    "DaemonConfig",
    "ImuConfig",
    "LidarConfig",
    "PanelConfig",
    "RecordingConfig",
    "ControlConfig",
    "HealthConfig",
    "StatusConfig",
    "ZenohAuthConfig",
    "ZenohConfig",
    "ZenohTlsConfig",
    "check_endpoint",
    "default_config_text",
    "load",
]


# Booleans take only true/false: the strict YAML loader keeps "yes"/"on" as strings and a
# StrictBool refuses them (and a quoted "true") rather than guessing.
Bool = StrictBool

_ENDPOINT = re.compile(r"^(?P<proto>[a-z][a-z0-9-]*)/(?P<addr>[^?#]*)(?P<rest>[?#].*)?$")
_IP_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
_OTHER_PROTOCOLS = ("unixsock-stream", "unixpipe", "serial", "vsock")
_HOSTNAME = re.compile(r"^(?=.{1,253}$)[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
                       r"(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*$")


def check_endpoint(ep: str) -> str:
    """A Zenoh endpoint ``proto/address[?metadata][#config]``; ValueError naming the problem.

    Zenoh itself accepts a malformed endpoint at open and just never listens on it, so the
    check is here: protocol known, and for IP protocols ``host:port`` with a port 0..65535.
    """
    m = _ENDPOINT.match(ep)
    if m is None:
        raise ValueError(f"endpoint {ep!r} is not proto/address (e.g. tcp/0.0.0.0:7447)")
    proto, addr = m["proto"], m["addr"]
    if proto in _OTHER_PROTOCOLS:
        if not addr:
            raise ValueError(f"endpoint {ep!r} has no address")
        return ep
    if proto not in _IP_PROTOCOLS:
        raise ValueError(f"endpoint {ep!r}: unknown protocol {proto!r} "
                         f"({', '.join(_IP_PROTOCOLS + _OTHER_PROTOCOLS)})")
    host, sep, port = addr.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"endpoint {ep!r}: needs host:port with a port 0..65535")
    if host.startswith("[") and host.endswith("]"):
        try:
            ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            raise ValueError(f"endpoint {ep!r}: {host} is not an IPv6 address") from None
    elif not _HOSTNAME.match(host):
        raise ValueError(f"endpoint {ep!r}: {host!r} is not a host name or address")
    elif host.replace(".", "").isdigit():
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            raise ValueError(f"endpoint {ep!r}: {host!r} is not an IPv4 address") from None
    return ep


def _existing_file(v: str) -> str:
    """'' stays ''; otherwise ``$VARS`` are expanded (``${CREDENTIALS_DIRECTORY}/name`` with
    systemd's LoadCredential=) and the file must exist."""
    if not v:
        return v
    path = os.path.expandvars(v)
    if not os.path.isfile(path):
        raise ValueError(f"file not found: {path}")
    return path


class LidarConfig(StrictModel):
    bind_address: str = "0.0.0.0"
    data_port: int = Field(DATA_PORT, ge=0, le=65535)  # 0: ephemeral (tests)
    position_port: int = Field(POSITION_PORT, ge=0, le=65535)  # 0: ephemeral; -1 not allowed
    position_enabled: Bool = True
    source_addresses: list[str] = []  # accept only these senders; empty: any
    receive_buffer_bytes: int = Field(64 << 20, ge=65536)  # SO_RCVBUF(FORCE) per socket [B]
    accept_products: list[int] = [PRODUCT_VLP16, PRODUCT_HDL32E]  # payload[1205]
    max_batch: int = Field(512, ge=1)  # datagrams read per wake-up and socket, at most
    batch_receive: Bool = True  # recvmmsg into MCAP-record rows (Linux); false: recvmsg each
    wake_interval_ms: float = Field(50.0, ge=0)  # sockets are drained at most this often [ms]
    switch_interval_ms: float = Field(0.5, gt=0)  # Python's GIL switch interval [ms]


class ImuConfig(StrictModel):
    url: str = ""  # pyserial URL: /dev/tripod-imu, /dev/pts/N, socket://localhost:4223; "" off
    driver: Literal["tfp", "witmotion"] = "tfp"
    baudrate: int = Field(115200, gt=0)
    tfp_uid: str = ""  # base58 UID of the IMU Brick 2.0; "": accept any, learn from enumerate
    quaternion_period_ms: int = Field(10, ge=1)  # TFP callback period asked of the brick [ms]
    reconnect_interval_s: float = Field(1.0, gt=0)
    read_size: int = Field(4096, ge=1)


class ZenohTlsConfig(StrictModel):
    certificate: str = ""  # this device's certificate (PEM), for tls/ listen endpoints
    private_key: str = ""  # its private key (PEM)
    client_ca: str = ""  # CA (PEM) that signed the clients' certificates: mutual TLS when set
    verify_name_on_connect: Bool = True  # check the name of a router we connect to

    @field_validator("certificate", "private_key", "client_ca")
    @classmethod
    def _files_exist(cls, v: str) -> str:
        return _existing_file(v)

    @model_validator(mode="after")
    def _pair(self):
        if bool(self.certificate) != bool(self.private_key):
            raise ValueError("certificate and private_key go together")
        return self


class ZenohAuthConfig(StrictModel):
    users_file: str = ""  # "user:password" lines; when set, every peer must log in
    user: str = ""  # our own login, for a router or peer that asks for one
    password_file: str = ""  # file holding that password (one line)

    @field_validator("users_file", "password_file")
    @classmethod
    def _files_exist(cls, v: str) -> str:
        return _existing_file(v)

    @model_validator(mode="after")
    def _pair(self):
        if bool(self.user) != bool(self.password_file):
            raise ValueError("user and password_file go together")
        return self


class ControlConfig(StrictModel):
    allow_loopback: Bool = True  # control from this machine (interface lo) without a login
    users: list[str] = []  # logins (auth.users_file) allowed to control
    cert_common_names: list[str] = []  # client certificate CNs (tls.client_ca) allowed to control
    max_label_bytes: int = Field(256, ge=0, le=65536)  # a mark label is short text [B]
    rate_per_s: float = Field(1.0, gt=0)  # commands per second, sustained
    burst: int = Field(10, ge=1)  # commands accepted back to back before the rate applies


class ZenohConfig(StrictModel):
    enabled: Bool = True
    mode: Literal["peer", "client", "router"] = "peer"
    listen: list[str] = ["tcp/0.0.0.0:7447"]  # where subscribers connect; []: zenoh's default
    connect: list[str] = []  # e.g. tcp/192.168.1.10:7447
    multicast_scouting: Bool = False
    config_file: str = ""  # a zenoh JSON5 config as the base; the keys above override it
    queue_messages: int = Field(50_000, ge=1)  # live-path queue; beyond it messages are dropped
    congestion_control: Literal["block", "drop"] = "drop"  # see publisher.py
    publish_lidar: Bool = True
    # live lidar blocks (tripod_shared.lidar_block) of at most this many bytes: the default fits
    # one zenoh batch (64 KiB), so a block is never cut into fragments (49 packets)
    lidar_block_bytes: int = Field(60_000, ge=1238)
    # zenoh batches (64 KiB each) queued per subscriber link for data before congestion control
    # drops: zenoh's default 2 is ~2 ms at 50,000 packets/s, 16 (its maximum) ~20 ms: a
    # subscriber that the scheduler leaves waiting a little does not lose data (1 MiB per link)
    tx_queue_batches: int = Field(16, ge=1, le=16)
    max_message_bytes: int = Field(1 << 20, ge=65536)  # larger zenoh messages are refused [B]
    tls: ZenohTlsConfig = ZenohTlsConfig()
    auth: ZenohAuthConfig = ZenohAuthConfig()
    control: ControlConfig = ControlConfig()

    @field_validator("config_file")
    @classmethod
    def _files_exist(cls, v: str) -> str:
        return _existing_file(v)

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, v: list[str]) -> list[str]:
        for ep in v:
            check_endpoint(ep)
        return v

    @model_validator(mode="after")
    def _consistent(self):
        if self.lidar_block_bytes > self.max_message_bytes:
            raise ValueError(f"lidar_block_bytes ({self.lidar_block_bytes}) is more than "
                             f"max_message_bytes ({self.max_message_bytes})")
        if any(ep.startswith("tls/") for ep in self.listen) and not self.tls.certificate:
            raise ValueError("a tls/ listen endpoint needs tls.certificate and tls.private_key")
        if self.control.users and not self.auth.users_file:
            raise ValueError("control.users needs auth.users_file (the logins to check)")
        if self.control.cert_common_names and not self.tls.client_ca:
            raise ValueError("control.cert_common_names needs tls.client_ca (mutual TLS)")
        return self


class RecordingConfig(StrictModel):
    enabled: Bool = True  # record from start-up (control/start and control/stop toggle it)
    directory: str = "/var/lib/tripod/recordings"
    prefix: str = "tripod"
    compression: Literal["zstd", "lz4", "none"] = "zstd"
    compression_level: int = Field(1, ge=-7, le=22)  # zstd level (1: fast; 3: 2.6x the CPU)
    chunk_size_bytes: int = Field(4 << 20, ge=1024)
    flush_interval_s: float = Field(0.25, gt=0)  # a chunk is written at least this often [s]
    fsync: Literal["chunk", "interval", "never"] = "chunk"
    fsync_interval_s: float = Field(5.0, gt=0)  # for fsync: interval
    max_file_bytes: int = Field(2 << 30, ge=0)  # split above this size; 0: never
    max_file_duration_s: float = Field(600.0, ge=0)  # split after this long; 0: never
    min_free_bytes: int = Field(256 << 20, ge=0)  # stop cleanly below this much free space
    queue_bytes: int = Field(32 << 20, ge=1 << 20)  # writer backlog budget; beyond: dropped [B]
    queue_max_age_s: float = Field(0.5, gt=0)  # nor older than this; beyond: dropped [s]
    retry_interval_s: float = Field(10.0, gt=0)  # retry a failed directory or full disk [s]

    @field_validator("prefix")
    @classmethod
    def _prefix_plain(cls, v: str) -> str:
        if not v or "/" in v or v.startswith("."):
            raise ValueError("must be a plain file-name prefix")
        return v


class StatusConfig(StrictModel):
    interval_s: float = Field(1.0, gt=0)  # status publish/record period [s]
    record: Bool = True  # also write the status into the recording


class HealthConfig(StrictModel):
    lidar_stall_s: float = Field(2.0, ge=0)  # no lidar data this long: flagged [s]; 0: off
    imu_stall_s: float = Field(2.0, ge=0)  # IMU connected but silent this long: flagged [s]
    unhealthy_restart_s: float = Field(300.0, ge=0)  # not recording though asked to, this long:
    # stop sending WATCHDOG=1 so systemd restarts the service [s]; 0: never


class PanelConfig(StrictModel):
    """``tripod-daemon panel`` (its own process and unit; the daemon itself ignores this)."""

    listen: str = "0.0.0.0:8443"  # host:port of the HTTPS page
    # "user:password" (one line): the page's password, and the panel's Zenoh login when the
    # daemon asks for one. Checked when the panel starts (the daemon does not need it).
    credentials_file: str = "${CREDENTIALS_DIRECTORY}/tripod_panel-credentials"
    # HTTPS certificate (PEM); "": zenoh.tls.certificate, else the device's certificate
    # ${CREDENTIALS_DIRECTORY}/tripod_device.pem
    certificate: str = ""
    private_key: str = ""  # its key (the same fallbacks)
    # the daemon's endpoint; "": the first tcp/ (else tls/) listen endpoint, on this machine
    connect: str = ""
    zenoh_ca: str = ""  # for a tls/ connect: the CA of the device's cert; "": tls.client_ca
    # for mutual TLS: the panel's client certificate and key; "": the device's own
    zenoh_certificate: str = ""
    zenoh_private_key: str = ""
    image_interval_s: float = Field(1.0, gt=0)  # range image refresh [s]
    session_hours: float = Field(12.0, gt=0)  # a login lasts this long [h]

    @field_validator("listen")
    @classmethod
    def _host_port(cls, v: str) -> str:
        host, sep, port = v.rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 < int(port) <= 65535:
            raise ValueError(f"{v!r} is not host:port (e.g. 0.0.0.0:8443)")
        return v

    @field_validator("connect")
    @classmethod
    def _endpoint(cls, v: str) -> str:
        return check_endpoint(v) if v else v


class DaemonConfig(StrictModel):
    device_id: str = topics.DEFAULT_DEVICE_ID
    log_level: Literal["debug", "info", "warning", "error"] = "info"
    lidar: LidarConfig = LidarConfig()
    imu: ImuConfig = ImuConfig()
    zenoh: ZenohConfig = ZenohConfig()
    recording: RecordingConfig = RecordingConfig()
    status: StatusConfig = StatusConfig()
    health: HealthConfig = HealthConfig()
    panel: PanelConfig = PanelConfig()

    @field_validator("device_id")
    @classmethod
    def _device_id_ok(cls, v: str) -> str:
        topics.key_status(v)  # raises ValueError naming the problem
        return v


def default_config_text() -> str:
    """The fully commented default config (the same text as ``deploy/etc/daemon.yaml``)."""
    return resources.files("tripod_daemon").joinpath("default_config.yaml").read_text("utf-8")


def load(
    config_path: str | None = None,
    overrides: dict | None = None,
    system_config: str | None = SYSTEM_CONFIG,
) -> DaemonConfig:
    """Effective config: system file (if it exists) < ``config_path`` < ``overrides``.

    Raises :class:`ConfigError` with one line naming the file and key on any problem.
    """
    paths: list[str] = []
    if system_config and os.path.exists(system_config):
        paths.append(system_config)
    if config_path:
        if not os.path.exists(config_path):
            raise ConfigError(f"config file not found: {config_path}")
        if not paths or os.path.realpath(config_path) != os.path.realpath(paths[0]):
            paths.append(config_path)
    return load_layered_config(DaemonConfig, paths, overrides, strict=True)
