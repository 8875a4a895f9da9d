# SPDX-License-Identifier: BSD-3-Clause
"""Fixtures shared by all tests: where the real public data lives (read-only, beside the repo)."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
VELODYNE = SHARED_DATA / "velodyne"
REGISTRATION = SHARED_DATA / "registration"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    assert SHARED_DATA.is_dir(), f"real test data expected at {SHARED_DATA}"
    return SHARED_DATA


@pytest.fixture(scope="session")
def velodyne_dir() -> Path:
    return VELODYNE


@pytest.fixture(scope="session")
def registration_dir() -> Path:
    return REGISTRATION
