# SPDX-License-Identifier: BSD-3-Clause
"""The per-recording manifest that lets a re-run skip finished work.

``<outdir>/<recording>/batch-manifest.json`` is written last, only after a reconstruction
succeeded. It holds the input fingerprint (every input file's resolved path, size and
mtime in ns), the SHA-256 of the effective config (YAML as written next to the outputs), and
every output file with its size. A recording is up to date when all three still match; any
difference (a touched or replaced input, another config, a deleted or truncated output)
reconstructs it again.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

MANIFEST = "batch-manifest.json"
VERSION = 1


def input_fingerprint(files: list[Path]) -> list[dict]:
    """[{path, size, mtime_ns}] of each input file (stat only: never reads the data)."""
    out = []
    for f in files:
        st = f.stat()
        out.append({"path": str(f.resolve()), "size": st.st_size, "mtime_ns": st.st_mtime_ns})
    return out


def config_hash(config_yaml: str) -> str:
    return hashlib.sha256(config_yaml.encode()).hexdigest()


def output_listing(outdir: Path) -> dict[str, int]:
    """{relative path: size} of every file under ``outdir`` except the manifest."""
    out = {}
    for f in sorted(outdir.rglob("*")):
        if f.is_file() and f.name != MANIFEST:
            out[f.relative_to(outdir).as_posix()] = f.stat().st_size
    return out


def write_manifest(outdir: Path, fingerprint: list[dict], cfg_hash: str, summary: dict) -> Path:
    """Write the manifest atomically (a crash never leaves one that claims a finished run)."""
    data = {"version": VERSION, "inputs": fingerprint, "config_sha256": cfg_hash,
            "outputs": output_listing(outdir), "summary": summary}
    path = outdir / MANIFEST
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1, sort_keys=True))
    os.replace(tmp, path)
    return path


def read_manifest(outdir: Path) -> dict | None:
    try:
        data = json.loads((outdir / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("version") == VERSION else None


def up_to_date(outdir: Path, fingerprint: list[dict], cfg_hash: str) -> tuple[bool, str]:
    """Whether the outputs in ``outdir`` are complete for these inputs and config, and if not
    why (one line)."""
    man = read_manifest(outdir)
    if man is None:
        return False, "no manifest (never finished)"
    if man.get("config_sha256") != cfg_hash:
        return False, "config changed"
    if man.get("inputs") != fingerprint:
        return False, "input changed"
    for rel, size in (man.get("outputs") or {}).items():
        f = outdir / rel
        if not f.is_file() or f.stat().st_size != size:
            return False, f"output {rel} missing or changed"
    if not man.get("outputs"):
        return False, "no outputs listed"
    return True, "up to date"
