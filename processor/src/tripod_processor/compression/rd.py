# SPDX-License-Identifier: BSD-3-Clause
"""Rate-distortion comparison of the tripod codec with Google Draco (``tripod rd``).

Draco (DracoPy, the processor's ``bench`` extra) runs at quantisation q bits (the bounding box's
largest side split into 2^q - 1 steps); the tripod codec runs on voxel grids of the same steps,
one octave beyond each end, so its curve brackets Draco's, in its default ``auto`` mode (learned
octree or predictive scan coding, whichever file is smaller at that step; ``mode`` records
it). The *ratio* compares rates at equal D1 PSNR: the tripod bits per point interpolated
(log-rate, linear in PSNR) at each Draco point, divided by Draco's. Rates are bits per input point; speeds are input points per second, wall
clock, with the threads the machine has; the ``*_cpu`` rates divide by the CPU time the process
used instead (all threads summed), a load-independent and conservative figure for a shared
machine.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import numpy as np

from .codec import encode, decode
from .metrics import d1
from .model import load_table


@dataclass
class RDPoint:
    """One operating point of one codec on one cloud."""

    codec: str  # "tripod" or "draco"
    q_bits: int  # quantisation bits of the step (the grid step is extent / (2^q - 1))
    step_m: float
    bpp: float  # bits per input point
    rmse_mm: float  # symmetric D1 RMSE
    psnr_diag_db: float
    psnr_mpeg10_db: float
    encode_mpts_s: float  # input points per second, wall clock [M/s]
    decode_mpts_s: float
    n_decoded: int
    encode_mpts_cpu_s: float = float("nan")  # input points per CPU second [M/s]
    decode_mpts_cpu_s: float = float("nan")
    mode: str = ""  # tripod: "octree" or "predictive" (what auto chose); draco: ""
    n_points: int = 0  # finite input points

    def as_dict(self) -> dict:
        return asdict(self)


def draco_available() -> bool:
    try:
        import DracoPy  # noqa: F401
    except ImportError:
        return False
    return True


def _timed(fn, *args, repeat: int = 1, **kw):
    """(result, best wall time [s], best CPU time [s]) over ``repeat`` runs."""
    wall, cpu, out = math.inf, math.inf, None
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        out = fn(*args, **kw)
        wall = min(wall, time.perf_counter() - t)
        cpu = min(cpu, time.process_time() - c)
    return out, wall, max(cpu, 1e-9)


def run_rd(points: np.ndarray, q_bits=range(8, 13), with_draco: bool = True,
           repeat: int = 1, progress=None, mode: str = "auto", origin=None) -> list[RDPoint]:
    """Measure both codecs on ``points`` (N, 3) [m]; returns all operating points.

    ``mode`` / ``origin``: the tripod codec's geometry mode and sensor origin (see
    :func:`.codec.encode`)."""
    p = np.ascontiguousarray(np.asarray(points, np.float32)[:, :3])
    p = p[np.isfinite(p).all(1)]
    n = len(p)
    ext = float((p.max(0) - p.min(0)).max())
    load_table()  # build the table once, outside the timings
    q_list = list(q_bits)
    ours_q = list(range(min(q_list) - 1, max(q_list) + 2))
    rows: list[RDPoint] = []
    jobs = [("tripod", q) for q in ours_q]
    if with_draco:
        jobs += [("draco", q) for q in q_list]
    for codec, q in jobs:
        step = ext / (2**q - 1)
        chosen = ""
        if codec == "tripod":
            (data, info), te, ce = _timed(encode, p, step, mode=mode, origin=origin,
                                          repeat=repeat)
            (dec, _hdr), td, cd = _timed(decode, data, repeat=repeat)
            chosen = info.mode
        else:
            import DracoPy

            data, te, ce = _timed(DracoPy.encode, p, quantization_bits=q, compression_level=10,
                                  repeat=repeat)
            mesh, td, cd = _timed(DracoPy.decode, data, repeat=repeat)
            dec = np.asarray(mesh.points, np.float32)
        m = d1(p, dec)
        rows.append(RDPoint(codec, q, step, 8.0 * len(data) / n, 1e3 * m.rmse_m, m.psnr_diag_db,
                            m.psnr_mpeg10_db, n / te / 1e6, n / td / 1e6, len(dec),
                            n / ce / 1e6, n / cd / 1e6, chosen, n))
        if progress is not None:
            progress(codec, q)
    return rows


def ratio_at_equal_psnr(rows: list[RDPoint]) -> dict[int, float]:
    """{Draco q: tripod bpp / Draco bpp at Draco's PSNR (diagonal peak)}, where bracketed."""
    ours = sorted((r for r in rows if r.codec == "tripod"), key=lambda r: r.psnr_diag_db)
    x = np.array([r.psnr_diag_db for r in ours])
    y = np.log(np.array([r.bpp for r in ours]))
    out = {}
    for r in rows:
        if r.codec != "draco" or len(ours) < 2:
            continue
        if x[0] <= r.psnr_diag_db <= x[-1]:
            out[r.q_bits] = float(np.exp(np.interp(r.psnr_diag_db, x, y)) / r.bpp)
    return out


def plot_rd(curves: dict[str, list[RDPoint]], path) -> None:
    """PNG of PSNR (diagonal peak) against bits per point, one panel per cloud."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from matplotlib.ticker import NullFormatter

    k = len(curves)
    cols = min(k, 2)
    rows_n = (k + cols - 1) // cols
    fig, axes = plt.subplots(rows_n, cols, figsize=(5.5 * cols, 4.0 * rows_n), squeeze=False)
    for ax in axes.flat[k:]:
        ax.set_visible(False)
    for ax, (name, rows) in zip(axes.flat, curves.items()):
        for codec, style in (("tripod", "o-"), ("draco", "s--")):
            rs = sorted((r for r in rows if r.codec == codec), key=lambda r: r.bpp)
            if rs:
                ax.plot([r.bpp for r in rs], [r.psnr_diag_db for r in rs], style,
                        label="tripod (auto)" if codec == "tripod" else "Draco q8-q12")
        pred = [r for r in rows if r.codec == "tripod" and r.mode == "predictive"]
        if pred:
            ax.plot([r.bpp for r in pred], [r.psnr_diag_db for r in pred], "D", ms=9,
                    mfc="none", mec="tab:red", label="  (auto chose predictive)")
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("bits per input point")
        ax.set_ylabel("D1 PSNR [dB] (peak: bbox diagonal)")
        ax.set_title(name)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def print_rd_tables(curves: dict) -> None:
    """One rich table per cloud: both codecs side by side at each q, and the rate ratio."""
    from rich.console import Console
    from rich.table import Table

    out = Console(width=max(Console().width, 150))
    for name, rows in curves.items():
        ratio = ratio_at_equal_psnr(rows)
        table = Table(title=f"{name}: rate-distortion (bpp per input point, D1 PSNR, speed M pts/s)")
        for col in ("codec", "mode", "q", "step mm", "bpp", "RMSE mm", "PSNR diag", "PSNR mpeg10",
                    "enc M/s", "dec M/s", "enc M/cpu-s", "dec M/cpu-s", "bpp ratio @ equal PSNR"):
            table.add_column(col, justify="right")
        for r in sorted(rows, key=lambda r: (r.q_bits, r.codec)):
            table.add_row(r.codec, r.mode, str(r.q_bits), f"{1e3 * r.step_m:.2f}", f"{r.bpp:.3f}",
                          f"{r.rmse_mm:.2f}", f"{r.psnr_diag_db:.2f}", f"{r.psnr_mpeg10_db:.2f}",
                          f"{r.encode_mpts_s:.2f}", f"{r.decode_mpts_s:.2f}",
                          f"{r.encode_mpts_cpu_s:.2f}", f"{r.decode_mpts_cpu_s:.2f}",
                          f"{ratio[r.q_bits]:.2f}" if r.codec == "draco" and r.q_bits in ratio
                          else "")
        out.print(table)
