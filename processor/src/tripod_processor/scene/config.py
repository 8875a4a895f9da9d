# SPDX-License-Identifier: BSD-3-Clause
"""Typed config of scene understanding (segment, planes, heightmaps), written beside outputs."""

from __future__ import annotations

from pydantic import Field

from tripod_shared.config_io import StrictModel


class SegmentConfig(StrictModel):
    weights: str | None = Field(None, description="segmenter weights (.npz); None = shipped weights")
    num_threads: int = Field(0, ge=0, description="CPU threads, 0 = all")
    plane_consistency: bool = Field(True, description="second stage: the points of one planar "
                                                      "segment agree")


class PlanesConfig(StrictModel):
    min_points: int = Field(500, ge=3, description="smallest planar segment [points]")
    min_area: float = Field(0.5, gt=0, description="smallest planar segment [m^2]")
    max_band: float = Field(0.10, gt=0, description="widest inlier band (3 sigma) [m]")
    min_band: float = Field(0.01, gt=0, description="narrowest inlier band [m]")
    normal_deg: float = Field(20.0, gt=0, le=90, description="normal agreement [deg]")
    gap: float = Field(0.30, gt=0, description="widest gap inside one segment [m]")
    seed: int = Field(0, description="RANSAC seed")


class HeightmapConfig(StrictModel):
    pixel: float = Field(0.05, gt=0, description="pixel edge [m]")
    behind: float = Field(0.10, ge=0, description="points this far behind the plane count [m]")
    relief: float = Field(0.40, gt=0, description="points this far in front of the plane count [m]")
    facing_deg: float = Field(60.0, gt=0, le=90, description="normal agreement with the plane [deg]")


class SceneConfig(StrictModel):
    segment: SegmentConfig = SegmentConfig()
    planes: PlanesConfig = PlanesConfig()
    heightmaps: HeightmapConfig = HeightmapConfig()
