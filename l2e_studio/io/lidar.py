"""Lidar scans from the file formats real rigs and datasets produce.

Every format ends up as a :class:`LidarScan`: float32 points (N,3) in the lidar frame and a
float32 intensity (N,) on the 0..255 scale the MI histograms use. Rows with a NaN/inf value
and zero returns (x = y = z = 0, which many drivers emit for "no echo") are dropped.

Formats (by suffix, see :data:`LIDAR_SUFFIXES`):

* ``.txt`` / ``.csv`` / ``.xyz`` -- the reference code's ``x,y,z,intensity`` one point a line,
  comma or whitespace separated; an optional header line names the columns.
* ``.pcd`` -- PCL point clouds, ``DATA ascii``, ``binary`` and ``binary_compressed`` (LZF).
* ``.ply`` -- ascii and binary (little/big endian) vertex elements.
* ``.bin`` -- KITTI velodyne scans (float32 x, y, z, reflectance); ``.pcd.bin`` is the
  nuScenes layout (float32 x, y, z, intensity, ring index).
* ``.npy`` / ``.npz`` -- an (N,>=3) array (4th column = intensity) or a structured array with
  fields x, y, z[, intensity]; an ``.npz`` holds ``points`` (+ optional ``intensity``) or
  ``x``, ``y``, ``z`` (+ ``intensity``) arrays.

Intensity scaling (:func:`scale_intensity`), whatever the native range:

* all values in [0, 1] (reflectivity as a fraction) -> multiplied by 255;
* values within [0, 255] -> kept as they are (8-bit intensities, the reference data);
* wider ranges (16-bit returns, raw signal strength) -> divided by the 99.5th percentile and
  multiplied by 255, so a few very bright retro-reflectors do not squash every other return
  into the lowest bins; the result is clipped to [0, 255];
* negative values (some drivers offset them) -> the minimum is shifted to 0 first.

Where a file has several candidate fields (``intensity``, ``reflectivity``, ``signal``...),
``intensity_field`` picks one; by default the first of :data:`INTENSITY_NAMES` present is used.
A file with no intensity gets a constant 0 intensity (the MI will be meaningless, so
:class:`LidarScan` records ``has_intensity=False`` for callers to warn about).
"""

from __future__ import annotations

import io
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_write_bytes
from ..errors import InputError
from . import _lzf
from ._table import count_rows
from .safe_load import NPZ_ERRORS, load_npy, open_npz

#: No lidar measures this far (metres): the longest-ranged survey scanners reach about 6 km,
#: automotive ones under 1 km. A point farther out on any axis is not a return in the lidar's own
#: frame (map coordinates, millimetres, or damaged data) and the scan is refused.
MAX_RANGE_M = 10_000.0

#: File suffixes :func:`load_lidar` reads (``.pcd.bin`` is matched before ``.bin``).
LIDAR_SUFFIXES: tuple[str, ...] = (".txt", ".csv", ".xyz", ".pcd", ".ply", ".pcd.bin", ".bin", ".npy", ".npz",
                                   ".las", ".laz")

#: Field names recognised as the laser ring (beam) number, in order of preference.
RING_NAMES: tuple[str, ...] = ("ring", "laser_id", "ring_id", "channel")
#: The largest ring index read (lidars have up to a few hundred beams); a larger one is no ring.
MAX_RING = 4096

#: Field names recognised as intensity, in order of preference.
INTENSITY_NAMES: tuple[str, ...] = ("intensity", "reflectivity", "reflectance", "i", "signal", "remission", "scalar_intensity")


@dataclass
class LidarScan:
    """One lidar scan: points (N,3) float32, intensity (N,) float32 in 0..255."""

    points: np.ndarray
    intensity: np.ndarray
    source: Path
    intensity_field: str | None = None
    has_intensity: bool = True
    ring: np.ndarray | None = None  # (N,) laser ring number, when the file has a ring field (RING_NAMES)

    def __len__(self) -> int:
        return int(self.points.shape[0])


def lidar_suffix(path: str | Path) -> str | None:
    """The entry of :data:`LIDAR_SUFFIXES` that ``path`` ends with, or None."""
    name = Path(path).name.lower()
    for suffix in LIDAR_SUFFIXES:
        if name.endswith(suffix):
            return suffix
    return None


def load_lidar(path: str | Path, intensity_field: str | None = None) -> LidarScan:
    """Read a lidar scan in any supported format (chosen by suffix)."""
    path = Path(path)
    suffix = lidar_suffix(path)
    if suffix is None:
        raise InputError(path, f"unknown lidar format; expected one of {', '.join(LIDAR_SUFFIXES)}")
    if not path.is_file():
        raise InputError(path, "lidar file not found")
    reader = _READERS[suffix]
    try:
        fields = reader(path)
    except InputError:
        raise
    except (*NPZ_ERRORS, IndexError) as exc:
        raise InputError(path, f"cannot read {suffix} lidar file ({exc})") from exc
    return _finish(path, fields, intensity_field)


def write_lidar_txt(path: str | Path, points: np.ndarray, intensity: np.ndarray) -> Path:
    """Write the reference ``x,y,z,intensity`` text format (one point a line)."""
    path = Path(path)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    intensity = np.asarray(intensity, dtype=np.float64).reshape(-1)
    if intensity.shape[0] != points.shape[0]:
        raise ValueError(f"{points.shape[0]} points but {intensity.shape[0]} intensities")
    buf = io.BytesIO()
    np.savetxt(buf, np.column_stack([points, intensity]), fmt=["%.6f", "%.6f", "%.6f", "%.3f"], delimiter=",")
    atomic_write_bytes(path, buf.getvalue())
    return path


def scale_intensity(values: np.ndarray) -> np.ndarray:
    """Map native intensities onto 0..255 (rules in the module docstring); float32 out."""
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return v.astype(np.float32)
    lo, hi = float(v.min()), float(v.max())
    if lo < 0:
        v = v - lo
        hi -= lo
    if hi <= 1.0:
        v = v * 255.0
    elif hi > 255.0:
        ref = float(np.percentile(v, 99.5))
        if ref <= 0:
            ref = hi
        v = v * (255.0 / ref)
    return np.clip(v, 0.0, 255.0).astype(np.float32)


# --- common tail ------------------------------------------------------------------------

def _finish(path: Path, fields: dict[str, np.ndarray], intensity_field: str | None) -> LidarScan:
    """Pick x/y/z + intensity out of named columns, drop bad rows, scale intensity."""
    lower = {k.lower(): k for k in fields}
    for axis in ("x", "y", "z"):
        if axis not in lower:
            raise InputError(path, f"no '{axis}' field; fields are {', '.join(fields) or 'none'}")
    xyz = np.column_stack([np.asarray(fields[lower[a]], dtype=np.float64).reshape(-1) for a in "xyz"])
    if intensity_field is not None:
        key = lower.get(intensity_field.lower())
        if key is None:
            raise InputError(path, f"no intensity field '{intensity_field}'; fields are {', '.join(fields)}")
    else:
        key = next((lower[n] for n in INTENSITY_NAMES if n in lower), None)
    if key is not None:
        raw = np.asarray(fields[key], dtype=np.float64).reshape(-1)
        if raw.shape[0] != xyz.shape[0]:
            raise InputError(path, f"{xyz.shape[0]} points but {raw.shape[0]} intensity values")
    else:
        raw = np.zeros(xyz.shape[0])
    if xyz.shape[0] == 0:
        raise InputError(path, "the point cloud is empty")
    ok = np.all(np.isfinite(xyz), axis=1) & np.isfinite(raw) & np.any(xyz != 0.0, axis=1)
    if not np.any(ok):
        raise InputError(path, f"none of the {xyz.shape[0]} points is valid (all NaN/inf or zero returns)")
    far = ok & np.any(np.abs(xyz) > MAX_RANGE_M, axis=1)
    if far.any():
        worst = float(np.abs(xyz[far]).max())
        raise InputError(path, f"{int(far.sum())} of {xyz.shape[0]} points lie farther than {MAX_RANGE_M / 1000:g} km "
                               f"(up to {worst:.3g} m), beyond any lidar's range: expected points in the lidar's own "
                               "frame, in metres (map coordinates, millimetres or damaged data?)")
    ring_key = next((lower[n] for n in RING_NAMES if n in lower), None)
    ring = None
    if ring_key is not None:
        values = np.asarray(fields[ring_key], dtype=np.float64).reshape(-1)
        # a ring index is a beam number, 0..MAX_RING; anything else (NaN, inf, 1e30, negative) is not
        # a ring field we can use
        if values.shape[0] == xyz.shape[0] and np.all((values[ok] >= 0) & (values[ok] <= MAX_RING)):
            ring = values[ok].astype(np.int32)
    return LidarScan(
        points=xyz[ok].astype(np.float32),
        intensity=scale_intensity(raw[ok]),
        source=path,
        intensity_field=key,
        has_intensity=key is not None,
        ring=ring,
    )


def _columns(path: Path, table: np.ndarray, names: list[str] | None) -> dict[str, np.ndarray]:
    """Name the columns of an (N, C) table: given names, else x,y,z,intensity,extra..."""
    if table.ndim != 2 or table.shape[1] < 3:
        raise InputError(path, f"expected at least 3 columns (x, y, z[, intensity]), got shape {table.shape}")
    if names is None:
        names = ["x", "y", "z", "intensity"][: table.shape[1]] + [f"col{i}" for i in range(4, table.shape[1])]
    return {n: table[:, i] for i, n in enumerate(names)}


# --- text -------------------------------------------------------------------------------

_NUMBER_START = re.compile(rb"^\s*[-+0-9.]|^\s*(nan|inf)", re.IGNORECASE)


def _read_text(path: Path) -> dict[str, np.ndarray]:
    data = path.read_bytes()
    pos = 0
    names: list[str] | None = None
    # Skip comment lines and one optional header line naming the columns.
    while pos < len(data):
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end
        line = data[pos:end]
        if not line.strip() or line.lstrip().startswith((b"#", b"//", b"%")):
            pos = end + 1
            continue
        if names is None and not _NUMBER_START.match(line):
            names = [t.decode("utf-8", "replace") for t in re.split(rb"[,\s;]+", line.strip()) if t]
            pos = end + 1
            continue
        break
    body = data[pos:].translate(_SEPARATORS)
    first = body.split(b"\n", 1)[0].split()
    if not first:
        raise InputError(path, "the point cloud is empty")
    ncols = len(first)
    if ncols < 3:
        raise InputError(path, f"expected 3 or more columns (x,y,z[,intensity]), the first data line has {ncols}")
    nlines = count_rows(path, body, ncols, data.count(b"\n", 0, pos) + 1)
    flat = _parse_numbers(path, body, ncols, "the text is not numeric")
    if flat.size != nlines * ncols:  # a token numpy's parser skipped or split differently
        _diagnose_text(path, body, ncols)
        raise InputError(path, f"ragged text: {flat.size} numbers is not {nlines} lines x {ncols} columns")
    if names is not None and len(names) != ncols:
        names = None
    return _columns(path, flat.reshape(nlines, ncols), names)


_SEPARATORS = bytes.maketrans(b",;\t\r", b"    ")


def _diagnose_text(path: Path, body: bytes, ncols: int) -> None:
    """Find the first bad line of a text cloud and raise an InputError naming it."""
    for number, line in enumerate(body.split(b"\n"), start=1):
        tokens = line.split()
        if not tokens:
            continue
        if len(tokens) != ncols:
            raise InputError(path, f"data line {number} has {len(tokens)} columns, expected {ncols}")
        try:
            [float(t) for t in tokens]
        except ValueError:
            raise InputError(path, f"data line {number} is not numeric: {line[:60].decode('utf-8', 'replace')!r}") from None


# --- PCD --------------------------------------------------------------------------------

_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8",
              ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}


def _read_pcd(path: Path) -> dict[str, np.ndarray]:
    data = path.read_bytes()
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            raise InputError(path, "PCD header has no DATA line")
        line = data[pos:end].decode("ascii", "replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            break
        if len(header) > 20:
            raise InputError(path, "not a PCD file (no DATA line in the header)")
    for key in ("FIELDS", "SIZE", "TYPE"):
        if key not in header:
            raise InputError(path, f"PCD header has no {key} line")
    fields, sizes, types = header["FIELDS"], header["SIZE"], header["TYPE"]
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
    if not (len(fields) == len(sizes) == len(types) == len(counts)):
        raise InputError(path, "PCD header FIELDS/SIZE/TYPE/COUNT lengths differ")
    npoints = int(header.get("POINTS", [0])[0]) if "POINTS" in header else \
        int(header.get("WIDTH", ["0"])[0]) * int(header.get("HEIGHT", ["1"])[0])
    dtypes = []
    for name, size, typ, count in zip(fields, sizes, types, counts):
        code = _PCD_TYPES.get((typ.upper(), int(size)))
        if code is None:
            raise InputError(path, f"PCD field {name!r} has unsupported TYPE {typ} SIZE {size}")
        dtypes.append((name, code, count))
    kind = header["DATA"][0].lower() if header["DATA"] else ""
    body = data[pos:]
    if kind == "ascii":
        table = _pcd_ascii(path, body, sum(counts), data.count(b"\n", 0, pos) + 1)
        columns, col = {}, 0
        for name, _, count in dtypes:
            columns[name] = table[:, col]
            col += count
        return _unique(columns)
    if kind == "binary":
        dt = np.dtype([(f"f{i}", "<" + code, (count,) if count > 1 else ()) for i, (_, code, count) in enumerate(dtypes)])
        need = npoints * dt.itemsize
        if len(body) < need:
            raise InputError(path, f"truncated binary PCD: {len(body)} bytes of data, header promises {need}")
        arr = np.frombuffer(body, dtype=dt, count=npoints)
        return _unique({name: _first(arr[f"f{i}"]) for i, (name, _, _) in enumerate(dtypes)})
    if kind == "binary_compressed":
        if len(body) < 8:
            raise InputError(path, "truncated binary_compressed PCD (no size words)")
        csize, usize = np.frombuffer(body[:8], dtype="<u4")
        if len(body) < 8 + int(csize):
            raise InputError(path, f"truncated binary_compressed PCD: {len(body) - 8} of {int(csize)} compressed bytes")
        point_bytes = sum(np.dtype("<" + code).itemsize * count for _, code, count in dtypes)
        if int(usize) != npoints * point_bytes:
            raise InputError(path, f"binary_compressed PCD: {int(usize)} uncompressed bytes declared, but "
                                   f"{npoints} points x {point_bytes} bytes = {npoints * point_bytes}")
        if int(usize) > _lzf.MAX_RATIO * int(csize) + 1024:
            raise InputError(path, f"binary_compressed PCD: {int(csize)} compressed bytes cannot hold the "
                                   f"{int(usize)} declared (LZF expands at most {_lzf.MAX_RATIO}x)")
        try:
            raw = _lzf.decompress(body[8: 8 + int(csize)], int(usize))
        except ValueError as exc:
            raise InputError(path, f"corrupt LZF data in binary_compressed PCD ({exc})") from exc
        # Column-major: each field's values for all points are stored together.
        columns, off = {}, 0
        for name, code, count in dtypes:
            item = np.dtype("<" + code)
            nbytes = item.itemsize * count * npoints
            if off + nbytes > len(raw):
                raise InputError(path, "binary_compressed PCD holds less data than its header says")
            vals = np.frombuffer(raw, dtype=item, count=count * npoints, offset=off).reshape(npoints, count)
            columns[name] = vals[:, 0]
            off += nbytes
        return _unique(columns)
    raise InputError(path, f"unknown PCD DATA encoding {kind!r}; expected ascii, binary or binary_compressed")


def _parse_numbers(path: Path, body: bytes, ncols: int, problem: str) -> np.ndarray:
    """All whitespace-separated numbers of ``body`` (fast C parser); a clear error otherwise."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            return np.fromstring(body.decode("ascii", "replace"), dtype=np.float64, sep=" ")
        except (DeprecationWarning, ValueError):
            _diagnose_text(path, body, ncols)
            raise InputError(path, problem) from None


def _pcd_ascii(path: Path, body: bytes, ncols: int, first_line: int) -> np.ndarray:
    body = body.translate(_SEPARATORS)
    nlines = count_rows(path, body, ncols, first_line)
    flat = _parse_numbers(path, body, ncols, "ascii PCD data is not numeric")
    if flat.size != nlines * ncols:
        _diagnose_text(path, body, ncols)
        raise InputError(path, f"ascii PCD data has {flat.size} numbers, not {nlines} lines x {ncols} columns")
    return flat.reshape(nlines, ncols)


def _first(a: np.ndarray) -> np.ndarray:
    return a[:, 0] if a.ndim > 1 else a


def _unique(columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Drop PCL padding fields (named ``_``)."""
    return {k: v for k, v in columns.items() if k != "_"}


# --- PLY --------------------------------------------------------------------------------

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _read_ply(path: Path) -> dict[str, np.ndarray]:
    data = path.read_bytes()
    if not data.startswith(b"ply"):
        raise InputError(path, "not a PLY file (does not start with 'ply')")
    end = data.find(b"end_header")
    if end < 0:
        raise InputError(path, "PLY header has no end_header")
    body_start = data.find(b"\n", end) + 1
    lines = data[:end].decode("ascii", "replace").splitlines()
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for line in lines:
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            elements.append((tok[1], int(tok[2]), []))
        elif tok[0] == "property":
            if not elements:
                raise InputError(path, "PLY property before any element")
            if tok[1] == "list":
                elements[-1][2].append((tok[-1], "list"))
            else:
                code = _PLY_TYPES.get(tok[1])
                if code is None:
                    raise InputError(path, f"PLY property type {tok[1]!r} unknown")
                elements[-1][2].append((tok[2], code))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(path, f"unknown PLY format {fmt!r}")
    if not elements or elements[0][0] != "vertex":
        raise InputError(path, "PLY file has no leading 'vertex' element")
    _, count, props = elements[0]
    if any(code == "list" for _, code in props):
        raise InputError(path, "PLY vertex element with list properties is not supported")
    body = data[body_start:]
    if fmt == "ascii":
        lines_b = body.split(b"\n", count)[:count]
        if len(lines_b) < count:
            raise InputError(path, f"truncated PLY: {len(lines_b)} of {count} vertex lines")
        flat = np.array(b" ".join(lines_b).split(), dtype=np.float64)
        if flat.size != count * len(props):
            raise InputError(path, f"PLY vertex lines hold {flat.size} numbers, expected {count} x {len(props)}")
        table = flat.reshape(count, len(props))
        return {name: table[:, i] for i, (name, _) in enumerate(props)}
    order = "<" if fmt == "binary_little_endian" else ">"
    dt = np.dtype([(name, order + code) for name, code in props])
    if len(body) < count * dt.itemsize:
        raise InputError(path, f"truncated PLY: {len(body)} bytes of vertex data, expected {count * dt.itemsize}")
    arr = np.frombuffer(body, dtype=dt, count=count)
    return {name: arr[name] for name, _ in props}


# --- binary and numpy -------------------------------------------------------------------

def _read_float_bin(path: Path, ncols: int, names: list[str]) -> dict[str, np.ndarray]:
    size = path.stat().st_size
    if size == 0:
        raise InputError(path, "the point cloud is empty")
    if size % (4 * ncols):
        raise InputError(path, f"file size {size} is not a multiple of {4 * ncols} bytes ({ncols} float32 per point)")
    table = np.fromfile(path, dtype="<f4").reshape(-1, ncols)
    xyz = table[:, :3]
    bad = ~np.all(np.isfinite(xyz) & (np.abs(xyz) < MAX_RANGE_M), axis=1) | ~np.isfinite(table[:, 3])
    if bad.mean() > 0.01:
        raise InputError(path, f"{int(bad.sum())} of {len(table)} points are NaN/inf or farther than "
                               f"{MAX_RANGE_M / 1000:g} km: not a float32 {'x y z intensity' + (' ring' if ncols == 5 else '')} "
                               "scan (random or other data?)")
    return {n: table[:, i] for i, n in enumerate(names)}


def _read_kitti(path: Path) -> dict[str, np.ndarray]:
    return _read_float_bin(path, 4, ["x", "y", "z", "intensity"])


def _read_nuscenes(path: Path) -> dict[str, np.ndarray]:
    return _read_float_bin(path, 5, ["x", "y", "z", "intensity", "ring"])


def _from_array(path: Path, arr: np.ndarray) -> dict[str, np.ndarray]:
    if arr.dtype.names:
        return {n: arr[n].reshape(-1) for n in arr.dtype.names}
    arr = np.asarray(arr)
    if arr.ndim != 2:
        raise InputError(path, f"expected an (N, 3+) array, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise InputError(path, f"expected a numeric array, got dtype {arr.dtype}")
    return _columns(path, arr, None)


def _read_npy(path: Path) -> dict[str, np.ndarray]:
    return _from_array(path, load_npy(path))


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    with open_npz(path) as z:
        keys = list(z.keys())
        if "points" in keys:
            cols = _from_array(path, z["points"])
            for k in keys:
                if k != "points" and z[k].ndim == 1:
                    cols[k] = z[k]
            return cols
        if {"x", "y", "z"} <= set(keys):
            return {k: z[k].reshape(-1) for k in keys if z[k].ndim <= 1 or z[k].shape[-1] == 1}
        if len(keys) == 1:
            return _from_array(path, z[keys[0]])
    raise InputError(path, f"npz holds {keys}; expected 'points' or 'x','y','z' arrays")


#: A LAZ file's points expand at most this much (LASzip reaches 5-15x on real scans).
MAX_LAZ_RATIO = 100


def _read_las(path: Path) -> dict[str, np.ndarray]:
    """LAS / LAZ through ``laspy`` (LAZ with its ``lazrs`` backend): scaled x, y, z and intensity.

    The header's point count is checked against the file size before anything is decompressed.
    """
    import laspy

    _check_las_header(path)
    try:
        with laspy.open(path) as reader:
            header = reader.header
            n, record = int(header.point_count), int(header.point_format.size)
            body = path.stat().st_size - int(header.offset_to_point_data)
            compressed = path.suffix.lower() == ".laz" or header.are_points_compressed
            if n * record > body * (MAX_LAZ_RATIO if compressed else 1):
                raise InputError(path, f"the header declares {n} points of {record} bytes, more than the "
                                       f"{body} bytes of point data can hold")
            las = reader.read()
    except laspy.errors.LaspyException as exc:
        raise InputError(path, f"cannot read the LAS/LAZ file ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
    fields = {"x": np.asarray(las.x), "y": np.asarray(las.y), "z": np.asarray(las.z)}
    if "intensity" in las.point_format.dimension_names:
        fields["intensity"] = np.asarray(las.intensity)
    return fields


def _check_las_header(path: Path) -> None:
    """Check the fixed LAS header's offsets and counts against the file's size before ``laspy``
    reads it (it reads up to the point-data offset the header states, and a flipped byte there
    asks for gigabytes)."""
    import struct

    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(375)
    if len(head) < 227 or head[:4] != b"LASF":
        raise InputError(path, "cannot read the LAS/LAZ file (no LASF signature or shorter than its 227-byte header)")
    header_size, offset, n_vlr = struct.unpack_from("<HII", head, 94)
    record = struct.unpack_from("<H", head, 105)[0]
    count = struct.unpack_from("<I", head, 107)[0]
    if head[25] >= 4 and len(head) >= 255:  # LAS 1.4: 64-bit count, extended VLRs
        count = struct.unpack_from("<Q", head, 247)[0] or count
        evlr_start, n_evlr = struct.unpack_from("<QI", head, 235)
        if n_evlr and (evlr_start > size or n_evlr * 60 > size - evlr_start):
            raise InputError(path, f"the header places {n_evlr} extended VLRs at byte {evlr_start} of a {size}-byte file")
    if not 227 <= header_size <= offset <= size:
        raise InputError(path, f"the header states a {header_size}-byte header and point data at byte {offset} "
                               f"of a {size}-byte file")
    if n_vlr * 54 > offset - header_size:
        raise InputError(path, f"the header declares {n_vlr} VLRs, more than the {offset - header_size} bytes "
                               "before the point data can hold")
    compressed = path.suffix.lower() == ".laz" or bool(head[104] & 0xC0)
    if count * record > (size - offset) * (MAX_LAZ_RATIO if compressed else 1):
        raise InputError(path, f"the header declares {count} points of {record} bytes, more than the "
                               f"{size - offset} bytes of point data can hold")
    if compressed:
        _check_laszip(path, header_size, n_vlr, offset, size, count)


#: LASzip writes chunks of 50 000 points by default; a chunk this large is a damaged header
#: (the decoder allocates a whole chunk up front).
MAX_LAZ_CHUNK = 5_000_000


def _check_laszip(path: Path, header_size: int, n_vlr: int, offset: int, size: int, count: int) -> None:
    """The LASzip VLR's chunk size and the chunk table's place and length, checked before the
    decoder trusts them (it allocates from them: a flipped byte asked for 34 GB and aborted)."""
    import struct

    with path.open("rb") as fh:
        fh.seek(header_size)
        vlrs = fh.read(offset - header_size)
        fh.seek(offset)
        table_at = fh.read(8)
        pos, chunk = 0, None
        for _ in range(n_vlr):
            if pos + 54 > len(vlrs):
                raise InputError(path, "the VLRs run past the point data")
            user, record_id, length = vlrs[pos + 2: pos + 18], *struct.unpack_from("<HH", vlrs, pos + 18)
            if user.rstrip(b"\0") == b"laszip encoded" and record_id == 22204 and length >= 16:
                chunk = struct.unpack_from("<I", vlrs, pos + 54 + 12)[0]
            pos += 54 + length
        if chunk is None:
            raise InputError(path, "compressed points but no LASzip VLR")
        if chunk != 0xFFFFFFFF and chunk > MAX_LAZ_CHUNK:
            raise InputError(path, f"the LASzip VLR states chunks of {chunk} points; at most {MAX_LAZ_CHUNK} are read")
        if len(table_at) < 8:
            raise InputError(path, "the file ends before its point data")
        table = struct.unpack("<q", table_at)[0]
        if table != -1:
            if not offset + 8 <= table <= size - 8:
                raise InputError(path, f"the LASzip chunk table is placed at byte {table} of a {size}-byte file")
            fh.seek(table)
            _, n_chunks = struct.unpack("<II", fh.read(8))
            if n_chunks > min(size, count + 1):
                raise InputError(path, f"the LASzip chunk table lists {n_chunks} chunks for {count} points "
                                       f"in a {size}-byte file")


_READERS = {
    ".txt": _read_text, ".csv": _read_text, ".xyz": _read_text,
    ".pcd": _read_pcd, ".ply": _read_ply, ".pcd.bin": _read_nuscenes, ".bin": _read_kitti,
    ".npy": _read_npy, ".npz": _read_npz, ".las": _read_las, ".laz": _read_las,
}
