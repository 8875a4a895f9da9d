#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# Reproduce the shipped segmenter weights (processor/src/tripod_processor/scene/segmentation/weights/).
# Training data: scans of generated buildings (tripod_processor.sim.procedural, train seeds 0-19
# of each of the seven layout families: rooms, corridor, hall, open_plan, L, U, apartment), two
# augmented copies each, 30 k sampled points per copy (train.RECIPE). Two stages (issue 18, fifth
# round): the first network as before, then an auto-context network (3 000 steps) on the features
# and the first one's probabilities over segments, wall planes, boxes and columns; the copies are
# kept whole in a temporary folder under $TMPDIR (~6 GB) meanwhile. bench/scene.py scores the
# weights on test seeds (1 000 000 ...) of every family and trains the leave-one-family-out
# models by the same recipe. CPU only, single-threaded training (9 000 + 3 000 steps: ~4 CPU
# minutes, plus the features of 140 buildings). Run from the repo root after `make setup`.
set -euo pipefail
.venv/bin/tripod train-segmenter \
  -o processor/src/tripod_processor/scene/segmentation/weights/segmenter.npz \
  --procedural 20 --families all --copies 2 --keep 30000 --steps 9000 --batch 4096 \
  --hidden 128,128 --stages 2 --hidden2 128,128 --steps2 3000 --lr 0.003 --class-power 0.25 --seed 0 --threads 1
