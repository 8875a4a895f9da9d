# SPDX-License-Identifier: BSD-3-Clause
"""Survey deliverables of a reconstruction: ``stations.e57`` (one scan per station with its pose)
and ``map.laz`` (the map as LAS 1.4 / LAZ), with intensity, station and segmentation label.

Frames and units: metres; the map frame is tripod's ``map`` (z up along gravity, origin at the
first station); an E57 scan's points are in its station frame (the lidar at the station's middle
time) and its pose is ``T_map_station`` (the same pose as ``stations.tum``).

Per-point attributes of the map (``map_voxel_m`` voxels, the map's own lattice):

* intensity: mean reflectivity of the fragment points of the voxel;
* station: the station that put the most points into the voxel;
* label: the segmenter's class of the map point (0 ceiling, 1 floor, 2 wall, 3 other), written
  to LAS as the ASPRS classification code of :data:`ASPRS_CLASS` and to E57 as ``tripod:label``
  (each station point takes the label of the map voxel it falls in; 255 where none).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.e57 import NO_LABEL, E57Scan
from ..io.las import LasCloud
from ..preprocess import lookup_keys, voxel_keys

#: segmentation label -> ASPRS LAS classification code (LAS 1.4 R15, table 17).
#: Indoor classes have no standard code: floor is "2 Ground" (the walkable surface, what ground
#: tools look for), walls "6 Building", ceiling the first user-definable code 64, "other"
#: "1 Unclassified"; a point without a label is "0 Created, never classified".
ASPRS_CLASS = {0: 64, 1: 2, 2: 6, 3: 1}
ASPRS_UNLABELLED = 0
ASPRS_NAMES = {0: "never classified", 1: "unclassified (tripod: other)",
               2: "ground (tripod: floor)", 6: "building (tripod: wall)",
               64: "user-defined: ceiling"}


def asprs_codes(labels: np.ndarray) -> np.ndarray:
    """(N,) uint8 ASPRS classification codes of segmentation labels (N,) (255: unlabelled)."""
    lut = np.full(256, ASPRS_UNLABELLED, np.uint8)
    for label, code in ASPRS_CLASS.items():
        lut[label] = code
    return lut[np.asarray(labels, dtype=np.int64) & 0xFF]


def labels_from_asprs(codes: np.ndarray) -> np.ndarray:
    """Inverse of :func:`asprs_codes` (codes not in the mapping give 255)."""
    lut = np.full(256, NO_LABEL, np.uint8)
    for label, code in ASPRS_CLASS.items():
        lut[code] = label
    return lut[np.asarray(codes, dtype=np.uint8)]


class _FragmentVoxels:
    """The main fragments' points (map frame) grouped by map voxel with one stable sort.

    Attributes: ``keys`` (M,) sorted unique voxel keys, ``run`` (N,) each point's voxel (index
    into ``keys``, in concatenation order), ``mean_intensity`` (M,) float32 (NaN: none),
    ``major`` (M,) index of the fragment with the most points in the voxel (ties: the first).
    """

    def __init__(self, frag_points_map: list[np.ndarray], frag_intensity: list[np.ndarray],
                 voxel_m: float):
        n = [len(p) for p in frag_points_map]
        keys = voxel_keys(np.concatenate(frag_points_map), voxel_m) if sum(n) else \
            np.zeros(0, np.int64)
        order = np.argsort(keys, kind="stable")  # equal keys keep the fragment order
        ks = keys[order]
        first = np.ones(len(ks), bool)
        first[1:] = ks[1:] != ks[:-1]
        run_sorted = np.cumsum(first) - 1
        m = int(first.sum())
        self.keys = ks[first]
        self.run = np.empty(len(ks), np.int64)
        self.run[order] = run_sorted
        self.offsets = np.concatenate([[0], np.cumsum(n)]).astype(np.int64)
        # mean intensity per voxel
        inten = np.concatenate(frag_intensity).astype(np.float64) if sum(n) else np.zeros(0)
        ok = np.isfinite(inten)
        s = np.bincount(self.run[ok], weights=inten[ok], minlength=m)
        c = np.bincount(self.run[ok], minlength=m)
        with np.errstate(invalid="ignore", divide="ignore"):
            self.mean_intensity = (s / c).astype(np.float32)
        # the fragment with the most points per voxel: (voxel, fragment) runs are contiguous
        # in the stable order, so their lengths need no second sort
        frag = np.repeat(np.arange(len(n)), n)[order]
        pair = np.ones(len(ks), bool)
        pair[1:] = first[1:] | (frag[1:] != frag[:-1])
        starts = np.flatnonzero(pair)
        length = np.diff(np.append(starts, len(ks)))
        seg_voxel, seg_frag = run_sorted[starts], frag[starts]
        best = np.full(m, -1, np.int64)
        if m:
            longest = np.maximum.reduceat(length, np.flatnonzero(first[starts]))
            win = length == longest[seg_voxel]
            # the first winning segment of each voxel (segments are in voxel order)
            w = np.flatnonzero(win)
            keep = np.ones(len(w), bool)
            keep[1:] = seg_voxel[w[1:]] != seg_voxel[w[:-1]]
            best[seg_voxel[w[keep]]] = seg_frag[w[keep]]
        self.major = best

    def at(self, query_keys: np.ndarray) -> np.ndarray:
        """Index into :attr:`keys` of each query key, -1 where absent."""
        return lookup_keys(self.keys, np.arange(len(self.keys)), query_keys, -1)


def map_attributes(frag_points_map: list[np.ndarray], frag_intensity: list[np.ndarray | None],
                   stations: list[int], centroids: np.ndarray, voxel_m: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Intensity (M,) float32 and station (M,) int32 of each map centroid (M, 3), from the
    fragments' points in the map frame, their intensities and station indices."""
    fi = [np.full(len(p), np.nan, np.float32) if i is None else i
          for p, i in zip(frag_points_map, frag_intensity)]
    return _map_attributes(_FragmentVoxels(frag_points_map, fi, voxel_m), stations, centroids,
                           voxel_m)


def _map_attributes(fv: _FragmentVoxels, stations: list[int], centroids: np.ndarray,
                    voxel_m: float) -> tuple[np.ndarray, np.ndarray]:
    idx = fv.at(voxel_keys(centroids, voxel_m))
    hit = idx >= 0
    inten = np.full(len(idx), np.nan, np.float32)
    inten[hit] = fv.mean_intensity[idx[hit]]
    station = np.full(len(idx), -1, np.int32)
    st = np.asarray(stations, np.int64)
    major = fv.major[idx[hit]]
    station[hit] = np.where(major >= 0, st[np.maximum(major, 0)], -1)
    return inten, station


def segment_labels(points: np.ndarray, num_threads: int = 0) -> np.ndarray:
    """(N,) uint8 labels of the map points (z up) by the shipped segmenter."""
    from ..scene.segmentation import Segmenter

    return np.asarray(Segmenter(num_threads=num_threads)(points), dtype=np.uint8)


@dataclass
class SurveyAttributes:
    """Per-point attributes of a run's map and of its main fragments (``main`` order)."""

    map_intensity: np.ndarray  # (M,) float32, NaN: unknown
    map_station: np.ndarray  # (M,) int32, -1: unknown
    map_label: np.ndarray  # (M,) uint8, 255: not labelled
    frag_intensity: list[np.ndarray]  # (N_k,) float32
    frag_label: list[np.ndarray]  # (N_k,) uint8


def survey_attributes(fragments, main: list[int], frag_points_map: list[np.ndarray],
                      centroids: np.ndarray, map_points: np.ndarray, voxel_m: float,
                      labels: bool, num_threads: int = 0) -> SurveyAttributes:
    """Attributes of the map points and of the main fragments' points (module docstring).

    Parameters
    ----------
    fragments : every Fragment of the run (``intensity`` filled, else NaN)
    main : indices of the stations in the map (the pose graph's main component)
    frag_points_map : the main fragments' points in the map frame, in ``main`` order
    centroids : (M, 3) the map's voxel centroids (before smoothing); ``map_points`` (M, 3) the
        map as written (smoothed, same order)
    labels : run the segmenter (else every label 255)
    """
    frag_int = [fragments[k].intensity if fragments[k].intensity is not None else
                np.full(len(fragments[k].points), np.nan, np.float32) for k in main]
    fv = _FragmentVoxels(frag_points_map, frag_int, voxel_m)
    inten, station = _map_attributes(fv, [fragments[k].station.index for k in main], centroids,
                                     voxel_m)
    lab = segment_labels(map_points, num_threads) if labels and len(map_points) > 10 else \
        np.full(len(map_points), NO_LABEL, np.uint8)
    # each fragment point takes the label of the map voxel it falls in (one lookup a voxel)
    ck = voxel_keys(centroids, voxel_m)
    order = np.argsort(ck, kind="stable")
    vox_label = lookup_keys(ck[order], lab[order], fv.keys, np.uint8(NO_LABEL)).astype(np.uint8)
    pt_label = vox_label[fv.run]
    frag_lab = [pt_label[fv.offsets[i]:fv.offsets[i + 1]] for i in range(len(main))]
    return SurveyAttributes(inten, station, lab, frag_int, frag_lab)


def map_las(map_points: np.ndarray, attrs: SurveyAttributes) -> LasCloud:
    """The map as a :class:`LasCloud` (labels as ASPRS codes)."""
    return LasCloud(np.asarray(map_points, np.float64), attrs.map_intensity, attrs.map_station,
                    asprs_codes(attrs.map_label))


def station_scans(fragments, main: list[int], T_map_station: np.ndarray,
                  attrs: SurveyAttributes) -> list[E57Scan]:
    """One :class:`E57Scan` per main station: its fragment in the station frame, its pose."""
    scans = []
    for i, k in enumerate(main):
        f = fragments[k]
        scans.append(E57Scan(f"station_{f.station.index:03d}", f.points.astype(np.float64),
                             T_map_station[i], attrs.frag_intensity[i], attrs.frag_label[i],
                             int(f.station.start_ns), int(f.station.end_ns)))
    return scans


def scans_from_folder(folder: str | os.PathLike) -> list[E57Scan]:
    """The station scans of a ``tripod reconstruct`` output folder: ``fragments/station_*.ply``
    (fields ``intensity`` and ``label`` when present), their poses from ``stations.tum`` (the
    stations of the map, in order; ``result.json`` names the disconnected ones, left out).
    Acquisition start and end are the station's middle time (the folder keeps no spans).

    Raises
    ------
    ValueError
        Not a reconstruction folder (one-line message).
    """
    import json

    from ..io.clouds import read_ply, xyz
    from .outputs import read_tum

    folder = Path(folder)
    tum, result, fdir = folder / "stations.tum", folder / "result.json", folder / "fragments"
    for p in (tum, result, fdir):
        if not p.exists():
            raise ValueError(f"{folder}: not a tripod reconstruct folder (no {p.name})")
    t_ns, T = read_tum(tum)
    disconnected = set(json.loads(result.read_text()).get("disconnected_stations", []))
    files = sorted(fdir.glob("station_*.ply"))
    main = [f for f in files if int(f.stem.split("_")[1]) not in disconnected]
    if len(main) != len(T):
        raise ValueError(f"{folder}: {len(main)} station fragments in the map but "
                         f"{len(T)} poses in stations.tum")
    scans = []
    for f, t, T_k in zip(main, t_ns, T):
        cloud = read_ply(f)
        names = cloud.dtype.names or ()
        n = len(cloud)
        inten = (np.asarray(cloud["intensity"], np.float32) if "intensity" in names
                 else np.full(n, np.nan, np.float32))
        lab = (np.asarray(cloud["label"]).astype(np.uint8) if "label" in names
               else np.full(n, NO_LABEL, np.uint8))
        scans.append(E57Scan(f.stem, xyz(cloud), T_k, inten, lab, int(t), int(t)))
    return scans
