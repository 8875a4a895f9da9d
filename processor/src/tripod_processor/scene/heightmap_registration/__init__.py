# SPDX-License-Identifier: BSD-3-Clause
"""Registration of two indoor scans by matching their plan heightmaps.

Both clouds are levelled on their floor plane (the IMU keeps them near gravity; the floor fixes
roll, pitch and height exactly), so only yaw and an x-y shift remain. Each scan becomes a *plan
heightmap*: an image over the floor whose pixels hold the height of the tallest point standing
there (walls reach the ceiling, furniture stops lower). Three matchers propose image transforms
(yaw, shift), each good where the others are weak:

1. **dense correlation** — for every yaw on a grid (2 deg) the source is turned and rasterised
   and the shift comes from an FFT cross-correlation with the target (walls and the rest as two
   channels); the best peaks of distinct yaws are kept (a rectangular room has two or four
   near-equal peaks: its symmetry twins);
2. **keypoints** — ORB (OpenCV) corners of the two heightmap images, matched by descriptor and
   filtered by a 2-D rigid RANSAC (two matches per hypothesis); the best consensus sets are kept;
3. **shapes** — the connected blobs of non-wall content (furniture, columns), described by their
   rotation-invariant Hu moments, area and height, matched and filtered by the same RANSAC.

Every proposal is refined by correlation at a finer pixel and yaw step, lifted to 3-D through the
two levelling transforms, polished by a short point-to-plane ICP on the registration core and
**verified in 3-D**: the share of the source's walls and furniture that land on target surfaces.
The twins of a symmetric room overlap equally well in floor, ceiling and bare walls; the
furniture and the relief of the walls (doors, windows, radiators) do not, so the verification,
not the image score, picks the answer. The winner is reported with its runner-up's score
(``ambiguity``): ``success`` needs enough verified overlap and a clear winner, so a pair that
does not overlap, or an empty symmetric room, comes back as a failure instead of a guess.

Exposed to ``tripod register`` as its heightmap method through :func:`register_by_heightmaps`.
"""

from .features import (hu_moments, match_binary, match_nearest, orb_keypoints, plan_image,
                       rigid_2d_ransac, shape_blobs)
from .levelling import LevelledScan, level_scan
from .pipeline import HeightmapMatch, register_by_heightmaps

__all__ = ["HeightmapMatch", "LevelledScan", "hu_moments", "level_scan", "match_binary",
           "match_nearest", "orb_keypoints", "plan_image", "register_by_heightmaps",
           "rigid_2d_ransac", "shape_blobs"]
