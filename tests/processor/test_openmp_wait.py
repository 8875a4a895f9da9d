# SPDX-License-Identifier: BSD-3-Clause
"""The OpenMP wait policy tripod_processor sets at import (README "Thread scaling")."""

import os

import tripod_processor


def test_user_choice_wins():
    env = {"OMP_WAIT_POLICY": "ACTIVE"}
    tripod_processor._openmp_wait_policy(env)
    assert env == {"OMP_WAIT_POLICY": "ACTIVE"}
    env = {"GOMP_SPINCOUNT": "0"}
    tripod_processor._openmp_wait_policy(env)
    assert env == {"GOMP_SPINCOUNT": "0"}


def test_passive_always_and_short_spin_only_on_a_quiet_machine(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    monkeypatch.setattr(os, "getloadavg", lambda: (0.3, 0.3, 0.3))
    env: dict = {}
    tripod_processor._openmp_wait_policy(env)
    assert env == {"OMP_WAIT_POLICY": "PASSIVE", "GOMP_SPINCOUNT": "30000"}
    monkeypatch.setattr(os, "getloadavg", lambda: (1.5, 1.0, 1.0))
    env = {}
    tripod_processor._openmp_wait_policy(env)
    assert env == {"OMP_WAIT_POLICY": "PASSIVE"}
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})  # one CPU: nothing to wait for
    monkeypatch.setattr(os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    env = {}
    tripod_processor._openmp_wait_policy(env)
    assert env == {"OMP_WAIT_POLICY": "PASSIVE"}


def test_no_load_average_means_passive(monkeypatch):
    def fail():
        raise OSError("no load average")
    monkeypatch.setattr(os, "getloadavg", fail)
    env: dict = {}
    tripod_processor._openmp_wait_policy(env)
    assert env == {"OMP_WAIT_POLICY": "PASSIVE"}
