# SPDX-License-Identifier: BSD-3-Clause
"""``python -m tripod_daemon``: the same as the ``tripod-daemon`` command."""

import sys

from .main import main

sys.exit(main())
