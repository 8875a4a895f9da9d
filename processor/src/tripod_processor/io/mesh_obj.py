# SPDX-License-Identifier: BSD-3-Clause
"""Wavefront OBJ meshes (+ MTL materials): the low-poly room for Blender, SketchUp, MeshLab,
ReCap and most CAD/BIM viewers.

Vertices are metres in tripod's map frame with **z up** (OBJ has no up axis; Blender: import
with "Up: Z"). Faces are grouped by class (``g``/``usemtl`` per class name), each class a
material with its diffuse colour in the ``.mtl`` written beside the ``.obj``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def write_obj(path: str | os.PathLike, vertices: np.ndarray, triangles: np.ndarray,
              classes: np.ndarray, class_names: list[str], class_colours: np.ndarray) -> None:
    """Write ``path`` (.obj) and the material file beside it (same stem, .mtl).

    Parameters
    ----------
    vertices : (V, 3) float [m]; triangles : (T, 3) int, 0-based vertex indices
    classes : (T,) int, index into ``class_names`` / ``class_colours`` ((C, 3) uint8 RGB)
    """
    path = Path(path)
    mtl = path.with_suffix(".mtl")
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    cls = np.asarray(classes, dtype=np.int64).reshape(-1)
    cols = np.asarray(class_colours, dtype=np.float64) / 255.0
    with open(mtl, "w", encoding="utf-8") as fh:
        fh.write("# tripod low-poly room materials: one per class\n")
        for name, c in zip(class_names, cols):
            fh.write(f"newmtl {name}\nKd {c[0]:.4f} {c[1]:.4f} {c[2]:.4f}\nKa 0 0 0\n"
                     "Ks 0 0 0\nd 1\nillum 1\n\n")
    lines = ["# tripod low-poly room model: metres, z up (map frame)\n",
             f"mtllib {mtl.name}\n"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in v]
    for k, name in enumerate(class_names):
        sel = tri[cls == k]
        if not len(sel):
            continue
        lines.append(f"g {name}\nusemtl {name}\n")
        lines += [f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in sel]
    with open(path, "w", encoding="utf-8") as fh:
        fh.writelines(lines)


def read_obj(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Vertices (V, 3), triangles (T, 3) 0-based and each triangle's group name of an OBJ
    written by :func:`write_obj` (triangles only; ``f`` entries may be ``v/vt/vn``)."""
    verts, tris, groups = [], [], []
    group = ""
    with open(path, encoding="utf-8") as fh:
        for ln in fh:
            parts = ln.split()
            if not parts:
                continue
            if parts[0] == "v":
                verts.append([float(x) for x in parts[1:4]])
            elif parts[0] == "g":
                group = parts[1] if len(parts) > 1 else ""
            elif parts[0] == "f":
                tris.append([int(p.split("/")[0]) - 1 for p in parts[1:4]])
                groups.append(group)
    return (np.asarray(verts, dtype=np.float64).reshape(-1, 3),
            np.asarray(tris, dtype=np.int64).reshape(-1, 3), groups)
