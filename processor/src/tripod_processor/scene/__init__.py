# SPDX-License-Identifier: BSD-3-Clause
"""Scene understanding on a registered cloud.

:mod:`.segmentation` (ceiling / floor / wall / other per point), :mod:`.planes` (planes per
class), :mod:`.heightmaps` (relief of each plane, low-poly mesh), :mod:`.heightmap_registration`
(scans registered by their floor and wall plans), :mod:`.config` (their settings),
:mod:`.plots` (pictures).
"""
