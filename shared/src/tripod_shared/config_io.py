# SPDX-License-Identifier: BSD-3-Clause
"""YAML config I/O for the components' typed (pydantic) configs.

Every config model derives from :class:`StrictModel`, so an unknown key is an error that names
the key; :func:`load_config` turns pydantic's report into one line a person can act on.
"""

from __future__ import annotations

import os
import re
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


class StrictYamlLoader(yaml.SafeLoader):
    """A safe loader for configs a person writes: a key given twice is an error (PyYAML keeps the
    last one silently), and only ``true``/``false`` are booleans (YAML 1.2 core schema; YAML
    1.1's ``yes``, ``no``, ``on``, ``off`` stay strings, which a boolean field then refuses)."""

    def construct_mapping(self, node, deep=False):
        seen: dict = {}
        for key_node, _value_node in node.value:
            key = self.construct_object(key_node, deep=True)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r} (first at line {seen[key] + 1})",
                    key_node.start_mark)
            seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)


StrictYamlLoader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag != "tag:yaml.org,2002:bool"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
StrictYamlLoader.add_implicit_resolver(
    "tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
    list("tTfF"))


def read_yaml(path: str | os.PathLike, strict: bool = False) -> dict:
    """The mapping in a YAML file. ``strict``: duplicate keys are errors and only
    ``true``/``false`` are booleans (:class:`StrictYamlLoader`)."""
    try:
        with open(path, encoding="utf-8") as fh:
            data = yaml.load(fh, Loader=StrictYamlLoader) if strict else yaml.safe_load(fh)
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {_yaml_error_line(exc)}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping of keys")
    return data


def _yaml_error_line(exc: yaml.YAMLError) -> str:
    problem = getattr(exc, "problem", None)
    mark = getattr(exc, "problem_mark", None)
    if problem and mark is not None:
        return f"{problem} (line {mark.line + 1})"
    return str(exc).splitlines()[0]


def load_config(
    model: type[M], path: str | os.PathLike | None = None, overrides: Mapping[str, Any] | None = None
) -> M:
    """Build a config: defaults < YAML file < overrides (nested dicts or 'a.b' dotted keys)."""
    return load_layered_config(model, [path] if path else [], overrides)


def load_layered_config(
    model: type[M],
    paths: "list[str | os.PathLike]",
    overrides: Mapping[str, Any] | None = None,
    strict: bool = False,
) -> M:
    """Build a config from several YAML files, later files overriding earlier ones key by key
    (e.g. ``/etc/tripod/daemon.yaml`` then ``--config``), then ``overrides``. ``strict``: see
    :func:`read_yaml`."""
    data: dict = {}
    for path in paths:
        data = _deep_merge(data, read_yaml(path, strict=strict))
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
