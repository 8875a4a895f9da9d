# SPDX-License-Identifier: BSD-3-Clause
"""Pictures of scene understanding (matplotlib, Agg): labelled clouds, heightmaps, overview."""

from __future__ import annotations

import numpy as np

CLASS_NAMES = ("ceiling", "floor", "wall", "other")
CLASS_RGB = np.array([[0.27, 0.51, 0.90], [0.78, 0.63, 0.24], [0.47, 0.75, 0.47], [0.80, 0.31, 0.31]])


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path, dpi: int) -> None:
    """PNG with a 256-colour palette: a few 100 kB instead of a MB, same look for these plots."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format="png")
    buf.seek(0)
    Image.open(buf).convert("RGB").quantize(256, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)


def _subsample(n: int, k: int, seed: int = 0) -> np.ndarray:
    return np.arange(n) if n <= k else np.sort(np.random.default_rng(seed).choice(n, k, replace=False))


def plot_labels(ax, points: np.ndarray, labels: np.ndarray, view: str = "top", max_points: int = 150_000,
                title: str = "") -> None:
    """Scatter of a labelled cloud: "top" (x-y, ceiling drawn last below walls) or "side" (x-z)."""
    idx = _subsample(len(points), max_points)
    p, lab = points[idx], np.clip(labels[idx], 0, 3)
    size = float(np.clip(3e4 / max(len(p), 1), 0.2, 2.0))
    if view == "top":  # the ceiling hides everything from above: leave it out
        keep = lab != 0
        order = np.argsort(np.select([lab[keep] == 1], [0], 1 + (lab[keep] == 3)), kind="stable")
        q, lq = p[keep][order], lab[keep][order]
        ax.scatter(q[:, 0], q[:, 1], s=size, c=CLASS_RGB[lq], linewidths=0)
        ax.set_xlabel("x [m]"), ax.set_ylabel("y [m]")
        ax.set_aspect("equal")
    else:
        ax.scatter(p[:, 0], p[:, 2], s=size, c=CLASS_RGB[lab], linewidths=0)
        ax.set_xlabel("x [m]"), ax.set_ylabel("z [m]")
        ax.set_aspect("auto")
    if title:
        ax.set_title(title, fontsize=9)


def legend(fig) -> None:
    from matplotlib.patches import Patch

    fig.legend([Patch(color=c) for c in CLASS_RGB], CLASS_NAMES, loc="lower center", ncol=4,
               fontsize=8, frameon=False)


def save_labels_picture(path, clouds: list[tuple[np.ndarray, np.ndarray, str]]) -> None:
    """One column per cloud: top view and side view, coloured by class."""
    plt = _plt()
    fig, axes = plt.subplots(2, len(clouds), figsize=(5.5 * len(clouds), 8.0), squeeze=False,
                             gridspec_kw={"height_ratios": [2.2, 1]})
    for j, (p, lab, title) in enumerate(clouds):
        # frame the room, not the few far returns through doors and windows
        lo, hi = np.nanpercentile(p, 2, axis=0), np.nanpercentile(p, 98, axis=0)
        sel = np.all((p >= lo - 1) & (p <= hi + 1), axis=1)
        plot_labels(axes[0, j], p[sel], lab[sel], "top", title=title + " (top, ceiling hidden)")
        plot_labels(axes[1, j], p[sel], lab[sel], "side", title=title + " (side)")
    legend(fig)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    _save(fig, path, 90)
    plt.close(fig)


def save_heightmaps_picture(path, heightmaps, max_tiles: int = 8, title: str = "") -> None:
    """Tiles of the largest heightmaps, coloured by height [cm] (holes white)."""
    plt = _plt()
    hms = sorted(heightmaps, key=lambda h: -np.isfinite(h.height).sum())[:max_tiles]
    n = max(1, len(hms))
    cols = min(4, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.9 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, hm in zip(axes.ravel(), hms):
        h = hm.height * 100
        im = ax.imshow(np.ma.masked_invalid(h), origin="lower", cmap="viridis",
                       vmin=-5, vmax=max(5.0, float(np.nanpercentile(h, 99)) if np.isfinite(h).any() else 5),
                       extent=(0, h.shape[1] * hm.pixel, 0, h.shape[0] * hm.pixel))
        ax.set_title(f"{CLASS_NAMES[hm.label]} {h.shape[1]}x{h.shape[0]} px", fontsize=8)
        ax.axis("on")
        ax.tick_params(labelsize=6)
        fig.colorbar(im, ax=ax, shrink=0.8, label="height [cm]")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    _save(fig, path, 72)
    plt.close(fig)


def save_overview(path, points, labels, planes, heightmaps, title: str = "") -> None:
    """Top view with the wall outlines and side view (top row); floor, ceiling and the two
    largest walls' heightmaps (bottom row)."""
    plt = _plt()
    fig = plt.figure(figsize=(14, 9.5))
    gs = fig.add_gridspec(2, 4, height_ratios=[1.5, 1])
    ax1 = fig.add_subplot(gs[0, :2])
    plot_labels(ax1, points, labels, "top", title="labels (top, ceiling hidden), plane outlines")
    for pl in planes:
        if len(pl.outline) >= 3 and pl.label in (1, 2):
            o = np.vstack([pl.outline, pl.outline[:1]])
            ax1.plot(o[:, 0], o[:, 1], "-" if pl.label == 2 else "--",
                     color="k" if pl.label == 2 else "saddlebrown", lw=0.9)
    ax2 = fig.add_subplot(gs[0, 2:])
    plot_labels(ax2, points, labels, "side", title="labels (side)")
    picks = [h for h in heightmaps if h.label in (0, 1)][:2]
    walls = sorted([h for h in heightmaps if h.label == 2], key=lambda h: -np.isfinite(h.height).sum())
    picks += walls[:4 - len(picks)]
    for k, hm in enumerate(picks[:4]):
        ax = fig.add_subplot(gs[1, k])
        h = hm.height * 100
        im = ax.imshow(np.ma.masked_invalid(h), origin="lower", cmap="viridis", vmin=-5, vmax=25,
                       extent=(0, h.shape[1] * hm.pixel, 0, h.shape[0] * hm.pixel), aspect="equal")
        ax.set_title(f"heightmap: {CLASS_NAMES[hm.label]} ({hm.pixel * 100:.0f} cm px)", fontsize=9)
        ax.set_xlabel("u [m]", fontsize=8)
        ax.set_ylabel("v [m]", fontsize=8)
        ax.tick_params(labelsize=7)
        fig.colorbar(im, ax=ax, shrink=0.8, label="height [cm]")
    legend(fig)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout(rect=(0, 0.04, 1, 0.97))
    _save(fig, path, 72)
    plt.close(fig)
