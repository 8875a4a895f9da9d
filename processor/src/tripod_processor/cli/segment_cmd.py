# SPDX-License-Identifier: BSD-3-Clause
"""``tripod segment`` and ``tripod train-segmenter``: floor / wall / ceiling / other labels."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from . import app
from ._common import UP_HELP, console, fail, read_points_up

CLASS_HELP = "0 ceiling, 1 floor, 2 wall, 3 other"


@app.command("segment", rich_help_panel="Scene understanding")
def segment_cmd(
    cloud: Path = typer.Argument(..., help="input cloud (PLY or PCD): with its up direction, "
                                           "or z up"),
    output: Path = typer.Option(..., "-o", "--output", help="labelled cloud (.ply or .pcd)"),
    up: str = typer.Option(None, "--up", help=UP_HELP),
    weights: Path = typer.Option(None, "--weights", help="segmenter weights (.npz); default: shipped"),
    truth_field: str = typer.Option(None, "--truth-field",
                                    help=f"score against this integer field of the input ({CLASS_HELP})"),
    threads: int = typer.Option(0, "--threads", help="CPU threads, 0 = all"),
    plane_consistency: bool = typer.Option(True, "--plane-consistency/--no-plane-consistency",
                                           help="second stage: the points of one planar segment agree"),
) -> None:
    """Label every point ceiling / floor / wall / other (field `label`: 0 ceiling, 1 floor,
    2 wall, 3 other). The output keeps the input's points, order, fields and up direction.
    A cloud with an up direction (its file's, or --up) is levelled before it is labelled."""
    import numpy as np
    from rich.table import Table

    from ..io.clouds import write_cloud
    from ..scene.config import SceneConfig, SegmentConfig
    from ..scene.segmentation import CLASS_NAMES, Segmenter
    from ..scene.segmentation.metrics import confusion, iou

    if output.suffix.lower() not in (".ply", ".pcd"):
        fail(f"output must end in .ply or .pcd, not {output.suffix!r}")
    src, pts, up_vec, up_from = read_points_up(cloud, up)
    if truth_field and truth_field not in src.dtype.names:
        fail(f"{cloud}: no field {truth_field!r} to score against")
    try:
        seg = Segmenter(weights, num_threads=threads, plane_consistency=plane_consistency)
    except (FileNotFoundError, ValueError, KeyError, OSError) as exc:
        fail(f"segmenter weights: {exc}")
    t0 = time.perf_counter()
    if up_vec is not None:  # the segmenter wants z up: label the levelled points
        from ..scene.gravity import level_points

        pts = level_points(pts, up_vec)[0]
    labels = seg(pts)
    dt = time.perf_counter() - t0
    names = [n for n in src.dtype.names if n != "label"]
    out = np.empty(len(src), dtype=[(n, src.dtype[n]) for n in names] + [("label", "<i4")])
    for n in names:
        out[n] = src[n]
    out["label"] = labels
    output.parent.mkdir(parents=True, exist_ok=True)
    write_cloud(output, out, up=up_vec)
    from tripod_shared.config_io import dump_config

    cfg = SceneConfig(segment=SegmentConfig(weights=str(weights) if weights else None,
                                            num_threads=threads,
                                            plane_consistency=plane_consistency))
    dump_config(cfg, output.with_name(output.stem + ".config.yaml"))
    table = Table(title=f"tripod segment: {len(pts):,} points in {dt:.2f} s "
                        f"({len(pts) / max(dt, 1e-9) / 1e6:.2f} M points/s)")
    table.add_column("class")
    table.add_column("points", justify="right")
    table.add_column("share", justify="right")
    if truth_field:
        table.add_column("IoU", justify="right")
        ious = iou(confusion(src[truth_field], labels))
    counts = np.bincount(labels, minlength=4)
    for k, name in enumerate(CLASS_NAMES):
        row = [name, f"{counts[k]:,}", f"{counts[k] / max(len(labels), 1):.1%}"]
        if truth_field:
            row.append(f"{ious[k]:.3f}")
        table.add_row(*row)
    console.print(table)
    if up_vec is not None:
        where = "--up" if up_from == "--up" else "the file"
        console.print(f"levelled by the up direction from {where}"
                      f" ({up_vec[0]:.3f}, {up_vec[1]:.3f}, {up_vec[2]:.3f})")


def _labelled_cloud(path: Path, label_field: str):
    """(points (N, 3) float32, labels (N,) int64) of a labelled PLY/PCD, an .npz with ``points``
    and ``labels``, or a ``tripod simulate`` capture folder (true poses and labels)."""
    import numpy as np

    from ..io.clouds import read_cloud, xyz

    if path.is_dir():
        from ..sim.fidelity import labeled_points

        p, lab, _ = labeled_points(path)
        return p.astype(np.float32), lab.astype(np.int64)
    if path.suffix.lower() == ".npz":
        with np.load(path) as z:
            if "points" not in z.files or "labels" not in z.files:
                raise ValueError("an .npz needs arrays 'points' and 'labels'")
            return z["points"].astype(np.float32), z["labels"].astype(np.int64)
    c = read_cloud(path)
    if label_field not in (c.dtype.names or ()):
        raise ValueError(f"no field {label_field!r} (use --label-field)")
    return xyz(c, dtype="float32"), c[label_field].astype(np.int64)


@app.command("train-segmenter", rich_help_panel="Scene understanding")
def train_segmenter_cmd(
    output: Path = typer.Option(..., "-o", "--output", help="weights file to write (.npz)"),
    data: list[Path] = typer.Option(None, "--data",
                                    help=f"labelled clouds: PLY/PCD with an integer field ({CLASS_HELP}; "
                                         f"255 = ignore), .npz with points + labels, `tripod simulate` "
                                         f"capture folders, or folders of these"),
    label_field: str = typer.Option("label", "--label-field", help="name of the truth field"),
    s3dis: Path = typer.Option(None, "--s3dis", help="S3DIS root (Area_N/<room>/Annotations)"),
    s3dis_areas: str = typer.Option("1,2,3,4,6", "--s3dis-areas", help="S3DIS areas to train on"),
    synthetic: int = typer.Option(0, "--synthetic",
                                  help="also generate this many labelled synthetic rooms"),
    procedural: int = typer.Option(0, "--procedural",
                                   help="also scan this many generated buildings of each layout "
                                        "family (sim.procedural, train seeds)"),
    families: str = typer.Option("all", "--families",
                                 help="layout families for --procedural (comma list, or all)"),
    keep: int = typer.Option(400_000, "--keep", help="sampled training points per cloud copy"),
    copies: int = typer.Option(2, "--copies", help="augmented copies of each cloud (first unperturbed)"),
    steps: int = typer.Option(2000, "--steps", help="optimiser steps"),
    batch: int = typer.Option(4096, "--batch", help="points per step"),
    hidden: str = typer.Option("128,128", "--hidden", help="hidden layer widths of the MLP"),
    stages: int = typer.Option(1, "--stages",
                               help="1: one network; 2: a second, auto-context network on the "
                                    "first one's probabilities over segments, planes, boxes and "
                                    "columns (whole copies kept in a temporary folder)"),
    hidden2: str = typer.Option("128,128", "--hidden2", help="hidden widths of the second stage"),
    steps2: int = typer.Option(0, "--steps2", help="optimiser steps of the second stage, 0 = --steps"),
    lr: float = typer.Option(3e-3, "--lr", help="peak learning rate (one cycle)"),
    class_power: float = typer.Option(0.5, "--class-power",
                                      help="class weights 1/frequency**power (0.5: 1/sqrt)"),
    seed: int = typer.Option(0, "--seed", help="seed of sampling, augmentation and init"),
    threads: int = typer.Option(0, "--threads", help="CPU threads, 0 = all"),
) -> None:
    """Train the per-point segmenter on labelled clouds (CPU, minutes) and write its weights."""
    import numpy as np
    from tqdm import tqdm

    from ..scene.segmentation.model import save_weights
    from ..scene.segmentation.train import features_of, train

    files: list[Path] = []
    for d in data or []:
        if d.is_dir() and (d / "labels.npz").is_file():
            files.append(d)  # a simulated capture
        elif d.is_dir():
            files += sorted(p for p in d.rglob("*") if p.suffix.lower() in (".ply", ".pcd", ".npz")
                            and p.name != "labels.npz")
            files += sorted(p.parent for p in d.rglob("labels.npz"))
        elif d.is_file():
            files.append(d)
        else:
            fail(f"no such file or folder: {d}")
    sources: list = []
    for f in files:
        try:
            sources.append(_labelled_cloud(f, label_field))
        except Exception as exc:  # noqa: BLE001 - any unreadable input is one line
            fail(f"{f}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}")
    if s3dis is not None:
        from ..scene.segmentation.s3dis import S3DISError, iter_rooms

        try:
            areas = [int(a) for a in s3dis_areas.split(",") if a.strip()]
            for room in iter_rooms(s3dis, areas):
                sources.append((room.points, room.labels4))
        except (S3DISError, ValueError) as exc:
            fail(str(exc))
    if synthetic:
        from ..sim.rooms import scan_room

        rng = np.random.default_rng(seed)
        for k in tqdm(range(synthetic), desc="synthetic rooms", unit="room"):
            p, lab, _ = scan_room(10_000 + seed * 1000 + k, n_stations=int(rng.integers(1, 3)),
                                  head_steps=int(rng.integers(6, 16)),
                                  noise_m=float(rng.uniform(0.005, 0.035)))
            sources.append((p, lab))
    fams: list[str] = []
    if procedural:
        from ..sim.procedural import FAMILIES

        fams = list(FAMILIES) if families.strip() == "all" else [
            f.strip() for f in families.split(",") if f.strip()]
        bad = [f for f in fams if f not in FAMILIES]
        if bad or not fams:
            fail(f"--families: unknown {', '.join(bad) or '(none)'} (choose from "
                 f"{', '.join(FAMILIES)} or all)")
    if not sources and not fams:
        fail("no training data: give --data, --s3dis, --synthetic or --procedural")
    hidden_sizes, hidden2_sizes = _widths(hidden, "--hidden"), _widths(hidden2, "--hidden2")
    if stages not in (1, 2):
        fail(f"--stages: 1 or 2, got {stages}")
    if steps2 < 0:
        fail(f"--steps2: 0 (= --steps) or more, got {steps2}")
    bar = tqdm(total=(len(sources) + procedural * len(fams)) * copies, desc="features",
               unit="cloud")
    if stages == 2:
        _train_two_stages(output, sources, fams, files, bar, procedural=procedural,
                          copies=copies, keep=keep, seed=seed, steps=steps, steps2=steps2 or steps,
                          batch=batch, hidden=hidden_sizes, hidden2=hidden2_sizes, lr=lr,
                          class_power=class_power, threads=threads, synthetic=synthetic,
                          s3dis=s3dis, s3dis_areas=s3dis_areas)
        return
    Fs, Ls = [], []
    if fams:  # generated buildings first, family by family (train.procedural_features)
        from ..scene.segmentation.train import procedural_features

        pf = procedural_features(fams, "train", procedural, copies, seed, keep,
                                 progress=lambda: bar.update())
        Fs += [pf[f][0] for f in fams]
        Ls += [pf[f][1] for f in fams]
    if sources:
        F, L = features_of(sources, copies=copies, seed=seed, progress=lambda: bar.update(),
                           keep_per_copy=keep)
        Fs.append(F)
        Ls.append(L)
    F, L = np.concatenate(Fs), np.concatenate(Ls)
    bar.close()
    bar = tqdm(total=steps, desc="training", unit="step")

    def prog(step, loss):
        bar.update()
        if step % 50 == 0:
            bar.set_postfix(loss=f"{loss:.4f}")

    model, rep = train(F, L, seed=seed, steps=steps, batch=batch, hidden=hidden_sizes, lr=lr,
                       class_power=class_power, num_threads=threads, progress=prog)
    bar.close()
    meta = _provenance(seed=seed, steps=steps, batch=batch, lr=lr, class_power=class_power,
                       copies=copies, synthetic=synthetic, procedural=procedural, fams=fams,
                       keep=keep, files=files, s3dis=s3dis, s3dis_areas=s3dis_areas,
                       seconds=rep.seconds, report=rep)
    save_weights(model, output, meta)
    _print_summary(output, len(sources) + procedural * len(fams), rep.points,
                   f"{steps} x {batch}", ("final loss", f"{rep.final_loss:.4f}"), rep.seconds)


def _widths(text: str, option: str) -> tuple[int, ...]:
    """Hidden layer widths from ``128,128``; a clear error naming ``option`` otherwise."""
    try:
        sizes = tuple(int(h) for h in text.split(",") if h.strip())
        if not sizes or min(sizes) < 1:
            raise ValueError
    except ValueError:
        fail(f"{option}: expected widths like 128,128, got {text!r}")
    return sizes


def _provenance(*, seed, steps, batch, lr, class_power, copies, synthetic, procedural, fams, keep,
                files, s3dis, s3dis_areas, seconds, report, **extra) -> dict:
    """The weight file's provenance: the training options, the data, the time and the command
    (``extra``: more options, e.g. the second stage's steps)."""
    import sys

    return {"seed": seed, "steps": steps, **extra, "batch": batch, "lr": lr,
            "class_power": class_power, "copies": copies, "synthetic": synthetic,
            "procedural": procedural, "families": fams, "keep": keep,
            "data": [str(f) for f in files], "s3dis": str(s3dis) if s3dis else None,
            "s3dis_areas": s3dis_areas if s3dis else None, "train_seconds": seconds,
            "points": report.points, "class_counts": report.class_counts,
            "command": "tripod " + " ".join(sys.argv[1:])}


def _print_summary(output: Path, clouds: int, points: int, steps_text: str,
                   loss: tuple[str, str], seconds: float) -> None:
    """The results table of ``train-segmenter``."""
    from rich.table import Table

    table = Table(title=f"tripod train-segmenter -> {output}")
    table.add_column("item")
    table.add_column("value", justify="right")
    table.add_row("clouds", str(clouds))
    table.add_row("training points", f"{points:,}")
    table.add_row("steps x batch", steps_text)
    table.add_row(*loss)
    table.add_row("training time [s]", f"{seconds:.1f}")
    table.add_row("weights [kB]", f"{output.stat().st_size / 1024:.1f}")
    console.print(table)


def _train_two_stages(output: Path, sources: list, fams: list, files: list, bar, *, procedural: int,
                      copies: int, keep: int, seed: int, steps: int, steps2: int, batch: int,
                      hidden: tuple, hidden2: tuple, lr: float, class_power: float, threads: int,
                      synthetic: int, s3dis, s3dis_areas: str) -> None:
    """``train-segmenter --stages 2``: the same copies and sampled points as one stage (the
    first network is the one-stage model), kept whole on disk for the second stage's context."""
    import tempfile

    from tqdm import tqdm

    from ..scene.segmentation.model import save_weights
    from ..scene.segmentation.train import (CopyStore, copies_of, procedural_copies,
                                            train_stacked)

    with tempfile.TemporaryDirectory(prefix="tripod-segmenter-") as tmp:
        store = CopyStore(tmp)
        for fam in fams:  # generated buildings first, as train.procedural_features draws them
            for c in procedural_copies(fam, procedural, copies, seed=seed, keep_per_copy=keep,
                                       progress=lambda: bar.update()):
                store.add(c)
        if sources:
            for c in copies_of(sources, copies, seed=seed, progress=lambda: bar.update(),
                               keep_per_copy=keep):
                store.add(c)
        bar.close()
        bar = tqdm(total=steps + steps2, desc="training (2 stages)", unit="step")

        def prog(step, loss):
            bar.update()
            if step % 50 == 0:
                bar.set_postfix(loss=f"{loss:.4f}")

        model, reps = train_stacked(store, seed=seed, steps=steps, steps2=steps2, batch=batch,
                                    lr=lr, hidden=hidden, hidden2=hidden2,
                                    num_threads=threads, class_power=class_power, progress=prog)
        bar.close()
    seconds = sum(r.seconds for r in reps)
    meta = _provenance(seed=seed, steps=steps, steps2=steps2, batch=batch, lr=lr,
                       class_power=class_power, copies=copies, synthetic=synthetic,
                       procedural=procedural, fams=fams, keep=keep, files=files, s3dis=s3dis,
                       s3dis_areas=s3dis_areas, seconds=seconds, report=reps[0])
    save_weights(model, output, meta)
    _print_summary(output, len(sources) + procedural * len(fams), reps[0].points,
                   f"{steps} + {steps2} x {batch}",
                   ("final loss (stage 1, 2)", f"{reps[0].final_loss:.4f}, {reps[1].final_loss:.4f}"),
                   seconds)


@app.command("s3dis-eval", rich_help_panel="Scene understanding")
def s3dis_eval_cmd(
    root: Path = typer.Argument(..., help="S3DIS root (Area_N/<room>/Annotations)"),
    protocol: str = typer.Option("area5", "--protocol", help="area5 or 6fold"),
    steps: int = typer.Option(1500, "--steps", help="optimiser steps per trained fold"),
    copies: int = typer.Option(1, "--copies", help="augmented copies of each training room"),
    seed: int = typer.Option(0, "--seed", help="training seed"),
    threads: int = typer.Option(0, "--threads", help="CPU threads, 0 = all"),
) -> None:
    """Standard S3DIS evaluation: train on the other areas, test on the held-out one (Area 5,
    or each area in turn for 6-fold); per-class IoU from the confusion summed over rooms/folds."""
    from rich.table import Table

    from ..scene.segmentation import Segmenter
    from ..scene.segmentation.metrics import iou, overall_accuracy
    from ..scene.segmentation.model import CLASS_NAMES
    from ..scene.segmentation.s3dis import S3DISError, area5_split, evaluate, six_fold_splits
    from ..scene.segmentation.train import features_of, train

    if protocol not in ("area5", "6fold"):
        fail(f"unknown protocol {protocol!r} (area5 or 6fold)")
    splits = area5_split() if protocol == "area5" else six_fold_splits()

    def train_fn(rooms):
        F, L = features_of([(r.points, r.labels4) for r in rooms], copies=copies, seed=seed)
        model, _ = train(F, L, seed=seed, steps=steps, num_threads=threads)
        return model

    def predict_fn(model, points):
        # the same two stages as `tripod segment`; non-finite points come out "other"
        return Segmenter(num_threads=threads, model=model)(points)

    try:
        total, per = evaluate(root, splits, train_fn, predict_fn)
    except S3DISError as exc:
        fail(str(exc))
    table = Table(title=f"S3DIS {protocol}: IoU from the summed confusion ({int(total.sum()):,} points)")
    table.add_column("class")
    table.add_column("IoU", justify="right")
    for name, v in zip(CLASS_NAMES, iou(total)):
        table.add_row(name, f"{v:.3f}")
    table.add_row("overall accuracy", f"{overall_accuracy(total):.3f}")
    console.print(table)
