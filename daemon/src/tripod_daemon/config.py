# SPDX-License-Identifier: BSD-3-Clause
"""The daemon's typed config (one pydantic model per component) and where it is searched.

Defaults here and the commented ``default_config.yaml`` shipped in the package (copied to
``deploy/etc/daemon.yaml``) must say the same thing; a test checks it. Files are layered:
``/etc/tripod/daemon.yaml`` (when present) < ``--config FILE`` < command-line flags.
"""

from __future__ import annotations

import os
from importlib import resources
from typing import Literal

from pydantic import Field, field_validator

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
    "RecordingConfig",
    "StatusConfig",
    "ZenohConfig",
    "default_config_text",
    "load",
]


class LidarConfig(StrictModel):
    bind_address: str = "0.0.0.0"
    data_port: int = Field(DATA_PORT, ge=0, le=65535)  # 0: ephemeral (tests)
    position_port: int = Field(POSITION_PORT, ge=0, le=65535)  # 0: ephemeral; -1 not allowed
    position_enabled: bool = True
    source_addresses: list[str] = []  # accept only these senders; empty: any
    receive_buffer_bytes: int = Field(64 << 20, ge=65536)  # SO_RCVBUF(FORCE) per socket [B]
    accept_products: list[int] = [PRODUCT_VLP16, PRODUCT_HDL32E]  # payload[1205]
    max_batch: int = Field(256, ge=1)  # datagrams read per readiness event before yielding


class ImuConfig(StrictModel):
    url: str = ""  # pyserial URL: /dev/tripod-imu, /dev/pts/N, socket://localhost:4223; "" off
    driver: Literal["tfp", "witmotion"] = "tfp"
    baudrate: int = Field(115200, gt=0)
    tfp_uid: str = ""  # base58 UID of the IMU Brick 2.0; "": accept any, learn from enumerate
    quaternion_period_ms: int = Field(10, ge=1)  # TFP callback period asked of the brick [ms]
    reconnect_interval_s: float = Field(1.0, gt=0)
    read_size: int = Field(4096, ge=1)


class ZenohConfig(StrictModel):
    enabled: bool = True
    mode: Literal["peer", "client", "router"] = "peer"
    listen: list[str] = ["tcp/0.0.0.0:7447"]  # where subscribers connect; []: zenoh's default
    connect: list[str] = []  # e.g. tcp/192.168.1.10:7447
    multicast_scouting: bool = False
    config_file: str = ""  # a zenoh JSON5 config as the base; the keys above override it
    queue_messages: int = Field(50_000, ge=1)  # live-path queue; beyond it messages are dropped
    congestion_control: Literal["block", "drop"] = "block"  # see publisher.py
    publish_lidar: bool = True


class RecordingConfig(StrictModel):
    enabled: bool = True  # record from start-up (control/start and control/stop toggle it)
    directory: str = "/var/lib/tripod/recordings"
    prefix: str = "tripod"
    compression: Literal["zstd", "lz4", "none"] = "zstd"
    chunk_size_bytes: int = Field(4 << 20, ge=1024)
    flush_interval_s: float = Field(1.0, gt=0)  # a chunk is written at least this often [s]
    fsync: Literal["chunk", "interval", "never"] = "chunk"
    fsync_interval_s: float = Field(5.0, gt=0)  # for fsync: interval
    max_file_bytes: int = Field(2 << 30, ge=0)  # split above this size; 0: never
    max_file_duration_s: float = Field(600.0, ge=0)  # split after this long; 0: never
    min_free_bytes: int = Field(256 << 20, ge=0)  # stop cleanly below this much free space
    queue_messages: int = Field(1_000_000, ge=1)  # writer queue; beyond it messages are lost

    @field_validator("prefix")
    @classmethod
    def _prefix_plain(cls, v: str) -> str:
        if not v or "/" in v or v.startswith("."):
            raise ValueError("must be a plain file-name prefix")
        return v


class StatusConfig(StrictModel):
    interval_s: float = Field(1.0, gt=0)  # status publish/record period [s]
    record: bool = True  # also write the status into the recording


class DaemonConfig(StrictModel):
    device_id: str = topics.DEFAULT_DEVICE_ID
    log_level: Literal["debug", "info", "warning", "error"] = "info"
    lidar: LidarConfig = LidarConfig()
    imu: ImuConfig = ImuConfig()
    zenoh: ZenohConfig = ZenohConfig()
    recording: RecordingConfig = RecordingConfig()
    status: StatusConfig = StatusConfig()

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
    return load_layered_config(DaemonConfig, paths, overrides)
