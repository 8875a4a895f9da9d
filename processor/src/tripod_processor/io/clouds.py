# SPDX-License-Identifier: BSD-3-Clause
"""Point cloud files: PLY (ascii / binary, any vertex fields) and PCD (ascii, binary,
binary_compressed), read and written without extra dependencies.

In memory a cloud is a numpy *structured* array with one named field per attribute
(``x, y, z`` [m] always; ``intensity``, ``ring``, ``time``, ``label``, normals ... as present).
:func:`xyz` gives the plain (N, 3) view most algorithms want.

A cloud may carry its **up direction** (the unit vector against gravity, in the cloud's own
frame): one header comment, ``comment tripod up X Y Z`` in PLY and ``# tripod up X Y Z`` in PCD.
Both formats define comments, so the usual readers (Open3D, PCL, plyfile) open the files as
before, and plyfile and PCL's own copies keep header comments as they are. :func:`read_cloud_meta`
returns the points with that metadata; :func:`write_cloud` writes it.
"""

from __future__ import annotations

import os
import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np


class CloudFormatError(ValueError):
    """The file is not a readable PLY/PCD cloud (message is one line)."""


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------
def xyz(cloud: np.ndarray, dtype=np.float64) -> np.ndarray:
    """(N, 3) array of the x, y, z fields of a structured cloud (or pass through an (N,3))."""
    if cloud.dtype.names is None:
        a = np.asarray(cloud, dtype=dtype)
        if a.ndim != 2 or a.shape[1] < 3:
            raise ValueError(f"expected (N,3) points, got {a.shape}")
        return a[:, :3]
    return np.stack([cloud["x"], cloud["y"], cloud["z"]], axis=1).astype(dtype, copy=False)


def make_cloud(points: np.ndarray, **fields: np.ndarray) -> np.ndarray:
    """Structured cloud from (N,3) points [m] plus named per-point fields."""
    p = np.asarray(points)
    n = len(p)
    dt = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    cols = {}
    for name, v in fields.items():
        v = np.asarray(v)
        if len(v) != n:
            raise ValueError(f"field {name!r} has {len(v)} values for {n} points")
        dt.append((name, v.dtype.newbyteorder("<").str))
        cols[name] = v
    out = np.empty(n, dtype=dt)
    out["x"], out["y"], out["z"] = p[:, 0], p[:, 1], p[:, 2]
    for k, v in cols.items():
        out[k] = v
    return out


@dataclass
class CloudMeta:
    """What a cloud file says about its frame, beyond the points.

    Attributes
    ----------
    up : (3,) float64 unit vector or None
        the direction against gravity in the cloud's frame (``tripod up`` header comment)
    viewpoint : (3,) float64 [m] or None
        the sensor position of a PCD file's ``VIEWPOINT`` line
    """

    up: np.ndarray | None = None
    viewpoint: np.ndarray | None = None


#: the header comment that carries the up direction (after "comment " in PLY, "# " in PCD)
UP_TAG = "tripod up"


def unit_up(up) -> np.ndarray:
    """``up`` as a (3,) float64 unit vector; ValueError for a wrong shape, a non-finite or a
    zero vector."""
    u = np.asarray(up, dtype=np.float64).reshape(-1)
    if u.shape != (3,) or not np.isfinite(u).all() or np.linalg.norm(u) < 1e-9:
        raise ValueError(f"an up direction needs three finite numbers, not all 0: {up!r}")
    return u / np.linalg.norm(u)


def _up_comment(up) -> str:
    u = unit_up(up)
    return f"{UP_TAG} {u[0]:.9f} {u[1]:.9f} {u[2]:.9f}"


def read_cloud_meta(path: str | os.PathLike) -> tuple[np.ndarray, CloudMeta]:
    """Read a PLY or PCD cloud (as :func:`read_cloud`) and its :class:`CloudMeta` (the up
    direction when the header carries one). A malformed ``tripod up`` comment is a
    CloudFormatError."""
    cloud = read_cloud(path)
    return cloud, read_meta(path)


def read_meta(path: str | os.PathLike) -> CloudMeta:
    """The :class:`CloudMeta` of a PLY/PCD file from its header alone."""
    up = None
    is_ply = False
    with open(path, "rb") as fh:
        for k in range(4096):  # a header is short; stop at its end
            raw = fh.readline(65536)
            if not raw:
                break
            line = raw.decode("ascii", errors="replace").strip()
            if k == 0 and line == "ply":
                is_ply = True
                continue
            if is_ply and line.startswith("comment ") or not is_ply and line.startswith("#"):
                text = line[len("comment "):] if is_ply else line.lstrip("#").strip()
                if text.startswith(UP_TAG + " ") or text == UP_TAG:
                    vals = text[len(UP_TAG):].split()
                    try:
                        up = unit_up([float(v) for v in vals])
                    except ValueError:
                        raise CloudFormatError(f"{path}: bad '{UP_TAG}' header comment "
                                               f"{text!r} (expected three numbers)") from None
            elif line.startswith("end_header") or line.upper().startswith("DATA"):
                break
    return CloudMeta(up=up, viewpoint=None if is_ply else pcd_viewpoint(path))


def read_cloud(path: str | os.PathLike) -> np.ndarray:
    """Read a PLY or PCD file into a structured array (format from the extension, else sniffed)."""
    path = Path(path)
    if path.is_dir():
        raise CloudFormatError(f"{path}: a folder, not a cloud file")
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    with open(path, "rb") as fh:
        head = fh.read(64)
    suffix = path.suffix.lower()
    if head.startswith(b"ply") or suffix == ".ply":
        return read_ply(path)
    if suffix == ".pcd" or b"PCD" in head or head.startswith(b"VERSION") or head.startswith(b"FIELDS"):
        return read_pcd(path)
    raise CloudFormatError(f"{path}: not a PLY or PCD file")


def write_cloud(path: str | os.PathLike, cloud: np.ndarray, up=None) -> None:
    """Write by extension: ``.ply`` (binary little-endian) or ``.pcd`` (binary); ``up`` (3,):
    the cloud's up direction, written as a header comment (see the module docstring)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".ply":
        write_ply(path, cloud, up=up)
    elif suffix == ".pcd":
        write_pcd(path, cloud, up=up)
    else:
        raise ValueError(f"unknown cloud extension {suffix!r} (use .ply or .pcd)")


def _as_structured(cloud: np.ndarray) -> np.ndarray:
    if cloud.dtype.names is not None:
        return cloud
    return make_cloud(np.asarray(cloud)[:, :3])


# ---------------------------------------------------------------------------------------------
# PLY
# ---------------------------------------------------------------------------------------------
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_NP_TO_PLY = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
              "u4": "uint", "f4": "float", "f8": "double", "i8": "double", "u8": "double"}


def read_ply(path: str | os.PathLike) -> np.ndarray:
    """Read the ``vertex`` element of a PLY file (ascii, binary_little_endian, binary_big_endian)."""
    with open(path, "rb") as fh:
        if fh.readline().strip() != b"ply":
            raise CloudFormatError(f"{path}: not a PLY file")
        fmt = None
        elements: list[tuple[str, int, list]] = []
        while True:
            line = fh.readline()
            if not line:
                raise CloudFormatError(f"{path}: PLY header has no end_header")
            tok = line.decode("ascii", errors="replace").split()
            if not tok or tok[0] in ("comment", "obj_info"):
                continue
            if tok[0] == "format":
                fmt = tok[1]
            elif tok[0] == "element":
                elements.append((tok[1], int(tok[2]), []))
            elif tok[0] == "property":
                if not elements:
                    raise CloudFormatError(f"{path}: PLY property before any element")
                if tok[1] == "list":
                    elements[-1][2].append((tok[4], "list", _PLY_TYPES[tok[2]], _PLY_TYPES[tok[3]]))
                else:
                    if tok[1] not in _PLY_TYPES:
                        raise CloudFormatError(f"{path}: unknown PLY type {tok[1]!r}")
                    elements[-1][2].append((tok[2], _PLY_TYPES[tok[1]]))
            elif tok[0] == "end_header":
                break
        if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
            raise CloudFormatError(f"{path}: unknown PLY format {fmt!r}")
        endian = ">" if fmt == "binary_big_endian" else "<"
        for name, count, props in elements:
            is_list = any(p[1] == "list" for p in props)
            if name == "vertex":
                if is_list:
                    raise CloudFormatError(f"{path}: list properties on vertices are not supported")
                dt = np.dtype([(p[0], endian + p[1]) for p in props])
                if count == 0:  # no vertices: nothing to parse (loadtxt would warn)
                    return np.empty(0, dtype=dt.newbyteorder("<"))
                if fmt == "ascii":
                    rows = [fh.readline() for _ in range(count)]
                    try:
                        data = np.loadtxt(rows, dtype=np.float64, ndmin=2)
                    except ValueError as exc:
                        raise CloudFormatError(f"{path}: bad PLY ascii vertex data: {exc}") from None
                    if data.shape[0] != count or data.shape[1] < len(props):
                        raise CloudFormatError(f"{path}: PLY vertex data is truncated")
                    out = np.empty(count, dtype=dt.newbyteorder("<"))
                    for i, p in enumerate(props):
                        out[p[0]] = data[:, i]
                    return out
                raw = fh.read(dt.itemsize * count)
                if len(raw) != dt.itemsize * count:
                    raise CloudFormatError(f"{path}: PLY vertex data is truncated")
                return np.frombuffer(raw, dtype=dt).astype(dt.newbyteorder("<"))
            # skip an element that precedes the vertices
            if fmt == "ascii":
                for _ in range(count):
                    fh.readline()
            elif not is_list:
                fh.seek(np.dtype([(p[0], p[1]) for p in props]).itemsize * count, 1)
            else:
                for _ in range(count):
                    for p in props:
                        if p[1] == "list":
                            cdt = np.dtype(endian + p[2])
                            (n,) = np.frombuffer(fh.read(cdt.itemsize), cdt)
                            fh.seek(int(n) * np.dtype(p[3]).itemsize, 1)
                        else:
                            fh.seek(np.dtype(p[1]).itemsize, 1)
    raise CloudFormatError(f"{path}: PLY file has no vertex element")


def write_ply(path: str | os.PathLike, cloud: np.ndarray, comments: list[str] | None = None,
              up=None) -> None:
    """Write a structured cloud as binary little-endian PLY (every field a vertex property);
    ``up`` (3,): its up direction, as the comment ``tripod up X Y Z``."""
    cloud = _as_structured(cloud)
    comments = list(comments or []) + ([_up_comment(up)] if up is not None else [])
    props = []
    cols = []
    for name in cloud.dtype.names:
        base = cloud.dtype[name].base
        if base.shape or base.kind not in "iuf":
            raise ValueError(f"field {name!r} of dtype {base} cannot be written to PLY")
        key = base.kind + str(base.itemsize)
        ply_t = _NP_TO_PLY.get(key)
        if ply_t is None:
            raise ValueError(f"field {name!r} of dtype {base} cannot be written to PLY")
        props.append(f"property {ply_t} {name}")
        cols.append((name, "<" + _PLY_TYPES[ply_t]))
    if np.dtype(cols) == cloud.dtype:
        out = cloud  # already the packed little-endian body: written as is, no field copies
    else:
        out = np.empty(len(cloud), dtype=cols)
        for name, _ in cols:
            out[name] = cloud[name]
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {c}" for c in (comments or [])]
    header += [f"element vertex {len(cloud)}", *props, "end_header"]
    with open(path, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        # a contiguous array is written from its own memory (no copy of the body)
        fh.write(out.data if out.flags.c_contiguous else out.tobytes())


# ---------------------------------------------------------------------------------------------
# PCD
# ---------------------------------------------------------------------------------------------
def lzf_decompress(data: bytes, expected_size: int) -> bytes:
    """LZF decompression (the codec of PCD ``binary_compressed``)."""
    out = bytearray()
    i, n = 0, len(data)
    try:
        while i < n:
            ctrl = data[i]
            i += 1
            if ctrl < 32:  # literal run of ctrl+1 bytes
                out += data[i : i + ctrl + 1]
                i += ctrl + 1
            else:  # back reference
                length = ctrl >> 5
                if length == 7:
                    length += data[i]
                    i += 1
                ref = len(out) - ((ctrl & 0x1F) << 8) - data[i] - 1
                i += 1
                length += 2
                if ref < 0:
                    raise CloudFormatError("corrupt LZF data (reference before start)")
                if ref + length <= len(out):
                    out += out[ref : ref + length]
                else:  # overlapping copy repeats the pattern
                    for k in range(length):
                        out.append(out[ref + k])
    except IndexError:
        raise CloudFormatError("corrupt LZF data (truncated)") from None
    if len(out) != expected_size:
        raise CloudFormatError(f"corrupt LZF data ({len(out)} bytes, expected {expected_size})")
    return bytes(out)


_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4",
              ("U", 8): "u8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8"}


def pcd_viewpoint(path: str | os.PathLike) -> np.ndarray | None:
    """The sensor position [m] of a PCD file's ``VIEWPOINT`` line ((3,) float64), or None for
    a PLY file, a PCD file without one, or an unreadable header."""
    try:
        with open(path, "rb") as fh:
            if fh.read(3) == b"ply":
                return None
            fh.seek(0)
            for _ in range(64):
                line = fh.readline(4096).decode("ascii", errors="replace").split()
                if not line:
                    continue
                key = line[0].upper()
                if key == "VIEWPOINT" and len(line) >= 4:
                    return np.array([float(v) for v in line[1:4]])
                if key == "DATA":
                    return None
    except (OSError, ValueError):
        return None
    return None


def read_pcd(path: str | os.PathLike) -> np.ndarray:
    """Read a PCD v0.5–0.7 file (DATA ascii, binary or binary_compressed)."""
    with open(path, "rb") as fh:
        raw = fh.read()
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise CloudFormatError(f"{path}: PCD header has no DATA line")
        line = raw[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        header[key.upper()] = vals
        if key.upper() == "DATA":
            break
    try:
        names = header["FIELDS"]
        sizes = [int(s) for s in header["SIZE"]]
        types = header["TYPE"]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(names))]
        npts = int(header.get("POINTS", [0])[0]) or int(header["WIDTH"][0]) * int(header.get("HEIGHT", ["1"])[0])
        data_kind = header["DATA"][0].lower()
    except (KeyError, ValueError, IndexError) as exc:
        raise CloudFormatError(f"{path}: bad PCD header ({exc})") from None
    fields = []
    for nm, sz, ty, ct in zip(names, sizes, types, counts):
        t = _PCD_TYPES.get((ty.upper(), sz))
        if t is None:
            raise CloudFormatError(f"{path}: unsupported PCD field type {ty}{sz}")
        fields.append((nm, "<" + t, (ct,)) if ct > 1 else (nm, "<" + t))
    # PCL pads with fields named "_": keep unique names
    seen: dict[str, int] = {}
    for k, f in enumerate(fields):
        if f[0] in seen or f[0] == "_":
            seen[f[0]] = seen.get(f[0], 0) + 1
            fields[k] = (f"_pad{k}",) + tuple(f[1:])
        else:
            seen[f[0]] = 1
    dt = np.dtype(fields)
    body = raw[pos:]
    if npts == 0:  # an empty cloud, whatever the DATA kind (loadtxt would warn, then fail)
        out = np.empty(0, dtype=dt)
    elif data_kind == "ascii":
        try:
            vals = np.loadtxt(body.decode("ascii").splitlines(), dtype=np.float64, ndmin=2)
        except ValueError as exc:
            raise CloudFormatError(f"{path}: bad PCD ascii data: {exc}") from None
        if vals.shape[0] < npts:
            raise CloudFormatError(f"{path}: PCD data is truncated ({vals.shape[0]} of {npts} points)")
        out = np.empty(npts, dtype=dt)
        col = 0
        for f, ct in zip(dt.names, counts):
            out[f] = vals[:npts, col] if ct == 1 else vals[:npts, col : col + ct]
            col += ct
    elif data_kind == "binary":
        if len(body) < dt.itemsize * npts:
            raise CloudFormatError(f"{path}: PCD data is truncated")
        out = np.frombuffer(body[: dt.itemsize * npts], dtype=dt).copy()
    elif data_kind == "binary_compressed":
        if len(body) < 8:
            raise CloudFormatError(f"{path}: PCD compressed data is truncated")
        csize, usize = struct.unpack_from("<II", body)
        buf = lzf_decompress(body[8 : 8 + csize], usize)
        # column-major: all values of field 0, then field 1, ...
        out = np.empty(npts, dtype=dt)
        off = 0
        for f in dt.names:
            fdt = dt[f]
            nbytes = fdt.itemsize * npts
            out[f] = np.frombuffer(buf[off : off + nbytes], dtype=fdt.base).reshape((npts,) + fdt.shape)
            off += nbytes
    else:
        raise CloudFormatError(f"{path}: unknown PCD DATA kind {data_kind!r}")
    keep = [n for n in out.dtype.names if not n.startswith("_pad")]
    return out[keep] if len(keep) != len(out.dtype.names) else out


def write_pcd(path: str | os.PathLike, cloud: np.ndarray, up=None) -> None:
    """Write a structured cloud as binary PCD v0.7 (scalar fields); ``up`` (3,): its up
    direction, as the header comment ``# tripod up X Y Z``."""
    cloud = _as_structured(cloud)
    up_line = f"# {_up_comment(up)}\n" if up is not None else ""
    names, sizes, types = [], [], []
    for name in cloud.dtype.names:
        base = cloud.dtype[name].base
        names.append(name)
        sizes.append(str(base.itemsize))
        types.append({"f": "F", "u": "U", "i": "I"}[base.kind])
    packed = np.empty(len(cloud), dtype=[(n, cloud.dtype[n].base.newbyteorder("<")) for n in names])
    for n in names:
        packed[n] = cloud[n]
    header = (
        f"# .PCD v0.7 - Point Cloud Data file format\n{up_line}VERSION 0.7\n"
        f"FIELDS {' '.join(names)}\nSIZE {' '.join(sizes)}\nTYPE {' '.join(types)}\n"
        f"COUNT {' '.join('1' for _ in names)}\nWIDTH {len(cloud)}\nHEIGHT 1\n"
        f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(cloud)}\nDATA binary\n"
    )
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(packed.tobytes())


def read_matrix4(path: str | os.PathLike) -> np.ndarray:
    """A 4x4 matrix from a text file (16 numbers, row-major; other text ignored)."""
    nums = re.findall(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?", Path(path).read_text())
    if len(nums) < 16:
        raise ValueError(f"{path}: expected 16 numbers for a 4x4 matrix, found {len(nums)}")
    return np.array([float(v) for v in nums[-16:]]).reshape(4, 4)
