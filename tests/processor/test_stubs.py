# SPDX-License-Identifier: BSD-3-Clause
"""The committed type stubs of the C++ extension match the compiled module (``make stubs``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import tripod_processor._ext as ext

STUB = Path(__file__).resolve().parents[2] / "processor/src/tripod_processor/_ext.pyi"


def test_committed_stub_matches_the_compiled_extension(tmp_path):
    fresh = tmp_path / "_ext.pyi"
    subprocess.run([sys.executable, "-m", "nanobind.stubgen", "-q", "-P", "-m", "tripod_processor._ext",
                    "-o", str(fresh)], check=True)
    assert STUB.read_text() == fresh.read_text(), \
        "processor/src/tripod_processor/_ext.pyi is out of date: run `make stubs` and commit it"


def test_every_public_binding_is_in_the_stub():
    text = STUB.read_text()
    names = [n for n in dir(ext) if not n.startswith("__")]
    assert len(names) > 20
    missing = [n for n in names
               if f"def {n}(" not in text and f"class {n}" not in text and f"{n}: " not in text]
    assert not missing, f"not in _ext.pyi: {missing}"
