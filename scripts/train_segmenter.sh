#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# Reproduce the shipped segmenter weights (processor/src/tripod_processor/segmentation/weights/).
# Training data: four simulated captures per scene type (tripod simulate, seeds 1-4: room,
# corridor, two_rooms, office, hall) plus 30 synthetic rooms; the benchmark tests on seed 101
# captures (bench/scene_data.py --split test), seed 102 is a second held-out draw (--split val).
# CPU only, a few minutes on 2 cores. Run from the repo root after `make setup`.
set -euo pipefail
PY=.venv/bin/python
$PY bench/scene_data.py --split train
.venv/bin/tripod train-segmenter \
  -o processor/src/tripod_processor/segmentation/weights/segmenter.npz \
  --data .cache/scene_data/train --synthetic 30 --copies 2 --steps 2000 --batch 4096 \
  --hidden 128,128 --seed 0
