# SPDX-License-Identifier: BSD-3-Clause
"""Issue 18, generator variants: the shipped two-stage weights and one leave-one-family-out
model, trained on the rows of a chosen generator version (``procedural.TALL_BY_GENERATOR``), each
exactly as ``train_stacked`` makes them (``scripts/train_segmenter.sh`` resp. ``bench/scene.py``'s
held-out models: the same copies, order, seed and recipe), sharing two passes over the copies,
which are recomputed (deterministic) instead of kept on disk (~6 GB). The held-out model is saved
with the bench's meta, so ``bench/scene.py --generator N --lofo-models DIR`` loads it.

Usage: ``python bench/segmenter_generator.py --generator 3 -o w.npz --lofo-models DIR
[--held-out hall] [--only-held] [--seed N]`` (``--seed``: the training seed, default 0, the recipe's;
another one measures the training noise) (one thread; ~25 min of CPU for both at load 5-10).
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ap.add_argument("--generator", type=int, required=True)
ap.add_argument("-o", "--output", type=Path, default=None, help="the shipped-recipe weights")
ap.add_argument("--lofo-models", type=Path, required=True)
ap.add_argument("--held-out", default="hall")
ap.add_argument("--only-held", action="store_true", help="the held-out model only")
ap.add_argument("--seed", type=int, default=0,
                help="training seed (0: the recipe's; another one measures the training noise)")
a = ap.parse_args()
if not a.only_held and a.output is None:
    ap.error("-o is needed unless --only-held")
out_shipped, lofo_dir, HELD, ONLY_HELD = a.output, a.lofo_models, a.held_out, a.only_held
# the provenance records the command that scripts/train_segmenter.sh gives
sys.argv = ["train-segmenter", "-o", str(out_shipped), "--procedural", "20", "--families", "all",
            "--copies", "2", "--keep", "30000", "--steps", "9000", "--batch", "4096",
            "--hidden", "128,128", "--stages", "2", "--hidden2", "128,128", "--steps2", "3000",
            "--lr", "0.003", "--class-power", "0.25", "--seed", str(a.seed), "--threads", "1"]
from tripod_processor.sim import procedural  # noqa: E402

procedural.GENERATOR = a.generator
from tripod_processor.cli.segment_cmd import _provenance  # noqa: E402
from tripod_processor.scene.segmentation.model import Stacked, save_weights  # noqa: E402
from tripod_processor.scene.segmentation.train import (RECIPE, procedural_copies,  # noqa: E402
                                                       stage2_rows, train)
from tripod_processor.sim.procedural import FAMILIES, GENERATOR  # noqa: E402

print("generator", GENERATOR, "held out", HELD, "only held", ONLY_HELD, flush=True)
kw = dict(seed=a.seed, batch=4096, lr=3e-3, num_threads=1, class_power=0.25)
t0 = time.time()


def log(*a):
    print(f"[{time.time() - t0:6.0f} s]", *a, flush=True)


# pass 1: the sampled rows of every copy, per family
rows = {}
for fam in FAMILIES:
    if ONLY_HELD and fam == HELD:
        continue
    F, L = [], []
    for c in procedural_copies(fam, 20):
        F.append(c.features[c.rows])
        L.append(c.labels)
    rows[fam] = (np.concatenate(F), np.concatenate(L))
    log("pass 1", fam, rows[fam][0].shape)
others = [f for f in FAMILIES if f != HELD]
s1 = {}
for name, fams in ((HELD, others), ("all", list(FAMILIES)))[:1 if ONLY_HELD else 2]:
    F = np.concatenate([rows[f][0] for f in fams])
    L = np.concatenate([rows[f][1] for f in fams])
    s1[name], r = train(F, L, steps=9000, hidden=(128, 128), **kw)
    s1[name + "_report"] = r
    log("stage 1 trained", name, f"{r.seconds:.0f} s")
del rows, F, L
# pass 2: stage 2 rows of each model over its families' whole copies (recomputed)
X = {HELD: [], "all": []}
for fam in FAMILIES:
    if ONLY_HELD and fam == HELD:
        continue
    copies = list(procedural_copies(fam, 20))
    for name in (HELD, "all")[:1 if ONLY_HELD else 2]:
        if name == HELD and fam == HELD:
            continue
        x, lab = stage2_rows(s1[name], copies)
        X[name].append((x.astype(np.float32), lab))  # train() casts to float32 anyway
    del copies
    log("pass 2", fam)
for name in (HELD, "all")[:1 if ONLY_HELD else 2]:
    Xs = np.concatenate([x[0] for x in X[name]])
    Ls = np.concatenate([x[1] for x in X[name]])
    s2, r2 = train(Xs, Ls, steps=3000, hidden=(128, 128), **kw)
    model = Stacked(s1[name], s2)
    r1 = s1[name + "_report"]
    if name == HELD:
        meta = {"held_out": HELD, "families": others, "per_family": 20, "steps": 9000,
                "recipe": {k: list(v) if isinstance(v, tuple) else v for k, v in RECIPE.items()},
                "seed": a.seed, "generator": GENERATOR}
        lofo_dir.mkdir(parents=True, exist_ok=True)
        fn = lofo_dir / f"lofo_{HELD}_20x9000.npz"
    else:
        meta = _provenance(seed=a.seed, steps=9000, steps2=3000, batch=4096, lr=0.003,
                           class_power=0.25, copies=2, synthetic=0, procedural=20,
                           fams=list(FAMILIES), keep=30000, files=[], s3dis=None,
                           s3dis_areas="1,2,3,4,6", seconds=r1.seconds + r2.seconds, report=r1)
        fn = out_shipped
    save_weights(model, fn, meta)
    log("saved", fn, f"stage 2 {r2.seconds:.0f} s")
