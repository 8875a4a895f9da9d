# SPDX-License-Identifier: BSD-3-Clause
"""``overview.png`` of a simulated capture: the scene from above, the route, the tripod's path
and every station with its heading."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .scenes import OTHER, WALL, Scene


def plot_overview(path: str | Path, scene: Scene, traj, route_xy: np.ndarray,
                  title: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection, PolyCollection

    tri = scene.vertices[scene.triangles]  # (T, 3, 3)
    fig, ax = plt.subplots(figsize=(9, 7), dpi=110)
    other = tri[scene.classes == OTHER][:, :, :2]
    if len(other):
        ax.add_collection(PolyCollection(other, facecolor="0.75", edgecolor="0.6",
                                         linewidths=0.6, label="other (furniture, pillars)"))
    wall = tri[scene.classes == WALL]
    n = np.cross(wall[:, 1] - wall[:, 0], wall[:, 2] - wall[:, 0])
    wall = wall[np.abs(n[:, 2]) < 0.5 * np.linalg.norm(n, axis=1)]  # vertical faces only
    if len(wall):
        segs = np.concatenate([wall[:, [0, 1]], wall[:, [1, 2]], wall[:, [2, 0]]])
        # horizontal edges of vertical faces are the walls' footprints
        flat = np.abs(segs[:, 0, 2] - segs[:, 1, 2]) < 1e-6
        segs = segs[flat][:, :, :2]
        segs = segs[np.linalg.norm(segs[:, 0] - segs[:, 1], axis=1) > 1e-6]
        ax.add_collection(LineCollection(segs, colors="k", linewidths=1.2, label="walls"))
    r = np.asarray(route_xy)
    ax.plot(r[:, 0], r[:, 1], ls=":", c="tab:gray", lw=1, label="route")
    t = np.linspace(0, traj.duration_s, 4000)
    _R, p = traj.T_world_base(t)
    ax.plot(p[:, 0], p[:, 1], c="tab:blue", lw=1.2, label="tripod path")
    lo, hi = scene.bounds
    arrow = 0.04 * max(hi[0] - lo[0], hi[1] - lo[1])
    for st in traj.stations:
        x, y = st.position[:2]
        ax.plot(x, y, "o", c="tab:red", ms=6)
        ax.annotate("", xy=(x + arrow * np.cos(st.yaw_rad), y + arrow * np.sin(st.yaw_rad)),
                    xytext=(x, y), arrowprops={"arrowstyle": "->", "color": "tab:red"})
        ax.text(x + 0.15, y + 0.15, str(st.index), fontsize=8, color="tab:red")
    pad = 0.05 * max(hi[0] - lo[0], hi[1] - lo[1])
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"{scene.name}: {len(traj.stations)} stations (red: heading)")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
