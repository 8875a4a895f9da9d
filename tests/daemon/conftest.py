# SPDX-License-Identifier: BSD-3-Clause
"""Daemon test fixtures: keep the ``tripod_daemon`` logger as it was around every test (a test
that runs ``main()`` installs a handler on a stream pytest closes afterwards)."""

import logging

import pytest


@pytest.fixture(autouse=True)
def _restore_daemon_logger():
    log = logging.getLogger("tripod_daemon")
    saved = (list(log.handlers), log.level, log.propagate)
    yield
    log.handlers[:], log.level, log.propagate = saved[0], saved[1], saved[2]
