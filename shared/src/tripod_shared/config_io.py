# SPDX-License-Identifier: BSD-3-Clause
"""YAML config I/O for the components' typed (pydantic) configs.

Every config model derives from :class:`StrictModel`, so an unknown key is an error that names
the key; :func:`load_config` turns pydantic's report into one line a person can act on.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

M = TypeVar("M", bound=BaseModel)


class ConfigError(ValueError):
    """A config file or override is wrong; the message is one line naming the key."""


class StrictModel(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


def _deep_merge(base: dict, over: Mapping) -> dict:
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), dict):
            out[k] = _deep_merge(out[k], v)
        else:
            out[k] = v
    return out


def _format_error(exc: ValidationError, source: str) -> str:
    parts = []
    for err in exc.errors():
        key = ".".join(str(p) for p in err["loc"])
        if err["type"] == "extra_forbidden":
            parts.append(f"unknown key '{key}'")
        else:
            parts.append(f"'{key}': {err['msg']}")
    return f"{source}: " + "; ".join(parts)


def read_yaml(path: str | os.PathLike) -> dict:
    try:
        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh)
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {str(exc).splitlines()[0]}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping of keys")
    return data


def load_config(
    model: type[M], path: str | os.PathLike | None = None, overrides: Mapping[str, Any] | None = None
) -> M:
    """Build a config: defaults < YAML file < overrides (nested dicts or 'a.b' dotted keys)."""
    return load_layered_config(model, [path] if path else [], overrides)


def load_layered_config(
    model: type[M],
    paths: "list[str | os.PathLike]",
    overrides: Mapping[str, Any] | None = None,
) -> M:
    """Build a config from several YAML files, later files overriding earlier ones key by key
    (e.g. ``/etc/tripod/daemon.yaml`` then ``--config``), then ``overrides``."""
    data: dict = {}
    for path in paths:
        data = _deep_merge(data, read_yaml(path))
    if overrides:
        nested: dict = {}
        for k, v in overrides.items():
            if v is None:
                continue
            cur = nested
            *head, last = str(k).split(".")
            for h in head:
                cur = cur.setdefault(h, {})
            cur[last] = v
        data = _deep_merge(data, nested)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        source = " + ".join(str(p) for p in paths) if paths else "config"
        raise ConfigError(_format_error(exc, source)) from None


def dump_config(cfg: BaseModel, path: str | os.PathLike | None = None) -> str:
    """YAML text of the effective config; written to ``path`` when given."""
    text = yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False)
    if path is not None:
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(text)
    return text
