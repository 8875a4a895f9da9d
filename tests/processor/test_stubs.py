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


def test_bindings_take_options_and_give_results_as_classes():
    """Issue 15: no binding takes a long positional list (settings cross as an option class) or
    hands back a dict (results are classes with named fields)."""
    import ast

    tree = ast.parse(STUB.read_text())
    long = []
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef):
            args = [a.arg for a in node.args.args + node.args.kwonlyargs if a.arg != "self"]
            if len(args) > 9:
                long.append(f"{node.name}({len(args)} arguments)")
            if node.returns is not None and ast.unparse(node.returns).startswith("dict"):
                long.append(f"{node.name} returns a dict")
    # the registration bindings are the i17 engineer's to convert
    long = [x for x in long if not x.startswith(("register", "_register", "oriented", "_oriented",
                                                 "prepare", "_prepare"))]
    assert not long, long
    for cls in ("_Vlp16DecoderConfig", "_PoseGraphOptions", "_SphericalGrid",
                "_ColumnContextOptions", "_PcapLayout"):
        getattr(ext, cls)()  # option classes are built empty and filled by name


def test_owned_arrays_keep_their_memory():
    """Arrays handed over by owned_array stay valid after the call's other results are gone
    (the capsule, not the call, owns them)."""
    import gc

    import numpy as np

    pts = np.random.default_rng(0).uniform(-1, 1, (5000, 3)).astype(np.float32)
    v = ext.voxel_assign(pts, 0.2, 1)
    counts, point_voxel = v.counts, v.point_voxel
    del v
    gc.collect()
    assert counts.sum() == len(pts) and point_voxel.max() == len(counts) - 1
    assert not counts.flags.owndata and counts.base is not None
    empty = ext.voxel_assign(np.zeros((0, 3), np.float32), 0.2, 1)
    assert empty.counts.shape == (0,) and empty.centroids.shape == (0, 3)
