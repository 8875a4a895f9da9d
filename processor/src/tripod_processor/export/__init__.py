# SPDX-License-Identifier: BSD-3-Clause
"""Exports of recordings to other tools' formats (``tripod export``)."""
