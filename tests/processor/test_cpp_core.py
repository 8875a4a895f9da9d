# SPDX-License-Identifier: BSD-3-Clause
"""Runs the C++ core's gtests (processor/cpp/tests), built with the extension by ``make setup``.

The gtests check tripod_core against PCL (voxel grid, k-d tree, normals), recover known
transforms with every registration method for 1, 2 and 4 threads (bit-identical results),
solve and reject outliers in a pose graph, and round-trip the range coder.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

import tripod_processor._ext  # noqa: F401  (an editable install rebuilds the tree on import)

BUILD = Path(__file__).resolve().parents[2] / "processor" / "build"


def _binary() -> Path:
    found = sorted(BUILD.glob("*/cpp/tests/tripod_core_tests"), key=lambda p: p.stat().st_mtime)
    if not found:
        pytest.fail("tripod_core_tests not built: run `make setup` (it builds the extension with "
                    "-DTRIPOD_BUILD_TESTS=ON; needs libgtest-dev)")
    return found[-1]


def test_cpp_core_gtests_pass():
    run = subprocess.run([str(_binary()), "--gtest_brief=1"], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    passed = re.search(r"\[  PASSED  \] (\d+) tests?", run.stdout)
    assert passed and int(passed.group(1)) >= 50, run.stdout[-2000:]
