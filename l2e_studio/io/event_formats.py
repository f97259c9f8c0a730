"""Event decoders for the non-Prophesee formats: AEDAT4, HDF5, npz/npy and text.

Each decoder yields ``(x, y, t_us, p)`` numpy arrays in chunks; :mod:`l2e_studio.io.events`
wraps them. Conventions are documented there.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import InputError
from ._table import count_rows
from .safe_load import NPZ_ERRORS, load_npy, open_npz

Arrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

_T_NAMES = ("t", "ts", "timestamp", "timestamps", "time", "t_us")
_P_NAMES = ("p", "pol", "polarity", "on")


def decoder(path: Path, suffix: str, chunk: int) -> Iterator[Arrays]:
    if suffix == ".aedat4":
        return _aedat4(path, chunk)
    if suffix in (".h5", ".hdf5"):
        return _hdf5(path, chunk)
    if suffix in (".npz", ".npy"):
        return _numpy(path, chunk)
    if suffix == ".txt":
        return _text(path, chunk)
    raise InputError(path, f"no decoder for {suffix}")


def sensor_size(path: Path, suffix: str) -> tuple[int, int] | None:
    """(width, height) as the file's metadata states it; None when it says nothing readable
    (the decoder then reports what is wrong with the file itself)."""
    try:
        if suffix == ".aedat4":
            import aedat  # type: ignore[import-not-found]

            for info in aedat.Decoder(str(path)).id_to_stream().values():
                if info.get("type") == "events" and info.get("width"):
                    return _whole(info["width"]), _whole(info["height"])
            return None
        if suffix in (".h5", ".hdf5"):
            import h5py

            with h5py.File(path, "r") as f:
                for node in (f, f.get("events"), f.get("CD")):
                    if node is None:
                        continue
                    attrs = node.attrs
                    if "width" in attrs and "height" in attrs:
                        return _whole(attrs["width"]), _whole(attrs["height"])
                    if "sensor_size" in attrs:
                        w, h = np.asarray(attrs["sensor_size"]).ravel()[:2]
                        return _whole(w), _whole(h)
                    if "geometry" in attrs:
                        m = re.match(r"(\d+)x(\d+)", str(attrs["geometry"]))
                        if m:
                            return int(m.group(1)), int(m.group(2))
            return None
        if suffix == ".npz":
            with open_npz(path) as z:
                if "sensor_size" in z.files:
                    w, h = z["sensor_size"].ravel()[:2]
                    return _whole(w), _whole(h)
                if "width" in z.files and "height" in z.files:
                    return _whole(z["width"]), _whole(z["height"])
            return None
        if suffix == ".txt":
            with open(path, "rb") as f:
                first = f.readline(256).split()
            if len(first) == 2 and all(t.isdigit() for t in first):
                return int(first[0]), int(first[1])
    except (OSError, ValueError, KeyError, RuntimeError, *NPZ_ERRORS):
        return None
    return None


def _whole(value) -> int:
    """One whole number from a metadata value (a scalar or a one-element array); ValueError otherwise."""
    a = np.asarray(value)
    if a.size != 1 or not np.issubdtype(a.dtype, np.number):
        raise ValueError(f"not a single number: {value!r}")
    v = float(a.reshape(()))
    if not np.isfinite(v) or v != round(v):
        raise ValueError(f"not a whole number: {value!r}")
    return int(v)


#: Largest |time| accepted, microseconds (about 146 000 years): int64 holds it with room to spare.
MAX_TIME_US = 2.0 ** 62


def _to_us(path: Path, t: np.ndarray, span_hint: float | None = None, seconds: bool | None = None) -> np.ndarray:
    """Event times as int64 microseconds. Integer times are microseconds; float times are seconds
    when ``seconds`` says so, else when the span (``span_hint`` or this array's) is < 1e4.
    NaN, infinite or out-of-range times cannot be placed in a window: refused, counted."""
    t = _column(path, t, "times")
    if np.issubdtype(t.dtype, np.integer) or np.issubdtype(t.dtype, np.bool_):
        if t.size and t.dtype == np.uint64 and int(t.max()) > MAX_TIME_US:
            raise InputError(path, f"event times up to {int(t.max())} us do not fit a 64-bit signed count")
        return t.astype(np.int64)
    bad = int(np.count_nonzero(~np.isfinite(t)))
    if bad:
        raise InputError(path, f"{bad} of {t.size} event times are NaN or infinite; such events cannot be placed "
                               "in a time window")
    if seconds is None:
        span = span_hint if span_hint is not None else (float(t.max() - t.min()) if t.size else 0.0)
        seconds = span < 1e4
    us = t * 1e6 if seconds else t.astype(np.float64)
    if us.size and float(np.abs(us).max()) > MAX_TIME_US:
        raise InputError(path, f"event times up to {float(np.abs(t).max()):.3g} {'s' if seconds else 'us'} are beyond any "
                               "clock (expected seconds or microseconds)")
    return np.rint(us).astype(np.int64)


def _column(path: Path, a: np.ndarray, what: str) -> np.ndarray:
    """``a`` as a 1-D numeric array, or an InputError naming what it holds."""
    a = np.asarray(a)
    if a.ndim != 1 or not (np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.bool_)):
        raise InputError(path, f"event {what} must be a 1-D array of numbers, got {a.dtype} of shape {a.shape}")
    return a


def _polarity(path: Path, p: np.ndarray) -> np.ndarray:
    p = _column(path, p, "polarities")
    if not np.issubdtype(p.dtype, np.integer) and not np.issubdtype(p.dtype, np.bool_) and not np.all(np.isfinite(p)):
        raise InputError(path, "event polarities have NaN or infinite values")
    return (p > 0).astype(np.uint8)


def _coords(path: Path, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x)
    y = np.asarray(y)
    if not all(np.issubdtype(a.dtype, np.number) and a.ndim == 1 for a in (x, y)) or x.shape != y.shape:
        raise InputError(path, f"event coordinates must be 1-D numbers, got {x.dtype} {x.shape} and {y.dtype} {y.shape}")
    if x.size and not (np.issubdtype(x.dtype, np.integer) and np.issubdtype(y.dtype, np.integer)):
        bad = int(np.count_nonzero(~(np.isfinite(x) & np.isfinite(y))))
        if bad:
            raise InputError(path, f"{bad} of {x.size} events have NaN or infinite coordinates")
        frac = int(np.count_nonzero((x != np.round(x)) | (y != np.round(y))))
        if frac:
            raise InputError(path, f"{frac} of {x.size} events have fractional pixel coordinates")
    if x.size and (x.min() < 0 or y.min() < 0):
        raise InputError(path, "negative event coordinates")
    if x.size and (x.max() > 65535 or y.max() > 65535):
        raise InputError(path, "event coordinates beyond 65535")
    return x.astype(np.uint16), y.astype(np.uint16)


# --- AEDAT4 ------------------------------------------------------------------------------

def _aedat4(path: Path, chunk: int) -> Iterator[Arrays]:
    try:
        import aedat  # type: ignore[import-not-found]
    except ImportError:
        raise InputError(path, "reading .aedat4 needs the 'aedat' package (pip install aedat)") from None
    with open(path, "rb") as f:
        if not f.read(14).startswith(b"#!AER-DAT4.0"):
            raise InputError(path, "not an AEDAT 4.0 file (missing '#!AER-DAT4.0' magic)")
    try:
        dec = aedat.Decoder(str(path))
        buf: list[np.ndarray] = []
        have = 0
        for packet in dec:
            if "events" not in packet:
                continue
            ev = packet["events"]
            buf.append(ev)
            have += ev.size
            if have >= chunk:
                yield _aedat_arrays(np.concatenate(buf))
                buf, have = [], 0
        if buf:
            yield _aedat_arrays(np.concatenate(buf))
    except InputError:
        raise
    except Exception as exc:  # the Rust decoder raises plain Exceptions on corrupt data
        raise InputError(path, f"corrupt AEDAT4 data ({exc})") from None


def _aedat_arrays(ev: np.ndarray) -> Arrays:
    return ev["x"].astype(np.uint16), ev["y"].astype(np.uint16), ev["t"].astype(np.int64), ev["on"].astype(np.uint8)


# --- HDF5 --------------------------------------------------------------------------------

#: What to say when an HDF5 dataset uses a compression filter h5py cannot decode.
HDF5_FILTER_HINT = ("compressed with an HDF5 filter h5py lacks (blosc, zstd, lz4...): pip install 'l2e-studio[hdf5]' "
                    "(hdf5plugin). Prophesee's ECF codec is not available in Python: convert the file with "
                    "metavision_file_to_hdf5 without --ecf, or to .raw/.dat")


def _hdf5(path: Path, chunk: int) -> Iterator[Arrays]:
    try:
        yield from _hdf5_events(path, chunk)
    except OSError as exc:
        if "filter" in str(exc).lower() or "plugin" in str(exc).lower():
            raise InputError(path, HDF5_FILTER_HINT) from None
        raise


def _hdf5_events(path: Path, chunk: int) -> Iterator[Arrays]:
    import h5py

    try:  # registers blosc/zstd/lz4/... filters with h5py when the [hdf5] extra is installed
        import hdf5plugin  # type: ignore[import-not-found]  # noqa: F401
    except ImportError:
        pass

    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputError(path, f"not a readable HDF5 file ({exc})") from None
    with f:
        offset = _h5_offset(path, f)
        group = None
        for cand in ("events", ""):
            if cand and cand not in f:
                continue
            g = f[cand] if cand else f
            if isinstance(g, h5py.Group) and all(k in g for k in ("x", "y")) and _pick(g, _T_NAMES) and _pick(g, _P_NAMES):
                group = g
                break
        if group is not None:
            names = {"x": "x", "y": "y", "t": _pick(group, _T_NAMES), "p": _pick(group, _P_NAMES)}
            ds = {k: group[v] for k, v in names.items()}
            for k, d in ds.items():
                if not isinstance(d, h5py.Dataset) or d.ndim != 1 or d.dtype.names is not None:
                    shape = d.shape if isinstance(d, h5py.Dataset) else "a group"
                    raise InputError(path, f"HDF5 event array {d.name} must be a 1-D dataset of numbers, got {shape}")
            n = ds["t"].shape[0]
            if not all(d.shape[0] == n for d in ds.values()):
                raise InputError(path, "HDF5 event arrays x, y, t, p have different lengths")
            span = _span(path, np.asarray([ds["t"][0], ds["t"][n - 1]]) if n else ds["t"][:0])
            for i in range(0, n, chunk):
                t = _to_us(path, ds["t"][i:i + chunk], span) + offset
                x, y = _coords(path, ds["x"][i:i + chunk], ds["y"][i:i + chunk])
                yield x, y, t, _polarity(path, ds["p"][i:i + chunk])
            return
        table = None
        for cand in ("events", "CD/events"):
            if cand in f and isinstance(f[cand], h5py.Dataset) and f[cand].dtype.names:
                table = f[cand]
                break
        if table is None:
            raise InputError(path, "no events found (expected events/{x,y,t,p}, root x,y,t,p or a compound 'events' table)")
        names = table.dtype.names
        tn, pn = _pick(names, _T_NAMES), _pick(names, _P_NAMES)
        if tn is None or pn is None or "x" not in names or "y" not in names:
            raise InputError(path, f"event table fields are {names}; expected x, y, t, p")
        if table.ndim != 1:
            raise InputError(path, f"the HDF5 event table {table.name} must be 1-D, got shape {table.shape}")
        try:
            for i in range(0, table.shape[0], chunk):
                rec = table[i:i + chunk]
                x, y = _coords(path, rec["x"], rec["y"])
                yield x, y, _to_us(path, rec[tn]) + offset, _polarity(path, rec[pn])
        except OSError as exc:
            if "filter" in str(exc).lower() or "plugin" in str(exc).lower():
                raise
            raise InputError(path, f"cannot read the event table ({exc})") from None


def _h5_offset(path: Path, f) -> int:
    """DSEC's root ``t_offset`` (microseconds added to every time): one whole number, or 0."""
    import h5py

    if "t_offset" not in f:
        return 0
    node = f["t_offset"]
    value = np.asarray(node[()]) if isinstance(node, h5py.Dataset) else None
    if value is None or value.size != 1 or not np.issubdtype(value.dtype, np.number):
        what = "a group" if value is None else f"{value.dtype} of shape {value.shape}"
        raise InputError(path, f"t_offset must be one number of microseconds, got {what}")
    v = value.reshape(()).item()
    if not (np.isfinite(v) and abs(v) <= MAX_TIME_US and float(v) == round(v)):
        raise InputError(path, f"t_offset must be a whole number of microseconds within ±2^62, got {v!r}")
    return int(v)


def _span(path: Path, t: np.ndarray) -> float:
    """max - min of event times (0 for none), for the seconds-or-microseconds rule."""
    t = _column(path, t, "times")
    return float(np.max(t)) - float(np.min(t)) if t.size else 0.0


def _pick(names, wanted) -> str | None:
    """The first of ``wanted`` that ``names`` (field names, npz files, an HDF5 group) holds."""
    return next((n for n in wanted if n in names), None)


# --- numpy -------------------------------------------------------------------------------

def _numpy(path: Path, chunk: int) -> Iterator[Arrays]:
    if path.suffix.lower() == ".npy":
        yield from _from_array(path, load_npy(path, mmap=True), chunk)
        return
    with open_npz(path) as z:
        files = z.files
        if "x" in files and "y" in files and _pick(files, _T_NAMES) and _pick(files, _P_NAMES):
            x, y = _column(path, z["x"], "x"), _column(path, z["y"], "y")
            t = _column(path, z[_pick(files, _T_NAMES)], "times")
            p = _column(path, z[_pick(files, _P_NAMES)], "polarities")
            if not (x.shape[0] == y.shape[0] == t.shape[0] == p.shape[0]):
                raise InputError(path, "npz event arrays x, y, t, p have different lengths")
            span = _span(path, t)
            for i in range(0, t.shape[0], chunk):
                xs, ys = _coords(path, x[i:i + chunk], y[i:i + chunk])
                yield xs, ys, _to_us(path, t[i:i + chunk], span), _polarity(path, p[i:i + chunk])
            return
        key = "events" if "events" in files else (files[0] if len(files) == 1 else None)
        if key is None:
            raise InputError(path, f"npz holds {files}; expected x, y, t, p arrays or an 'events' array")
        yield from _from_array(path, z[key], chunk)


def _from_array(path: Path, arr: np.ndarray, chunk: int) -> Iterator[Arrays]:
    if arr.dtype.names:
        names = arr.dtype.names
        tn, pn = _pick(names, _T_NAMES), _pick(names, _P_NAMES)
        if tn is None or pn is None or "x" not in names or "y" not in names:
            raise InputError(path, f"event array fields are {names}; expected x, y, t, p")
        if arr.ndim != 1:
            raise InputError(path, f"a structured event array must be 1-D, got shape {arr.shape}")
        span = _span(path, arr[tn])
        for i in range(0, arr.shape[0], chunk):
            rec = arr[i:i + chunk]
            x, y = _coords(path, rec["x"], rec["y"])
            yield x, y, _to_us(path, rec[tn], span), _polarity(path, rec[pn])
        return
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise InputError(path, f"expected a structured event array or (N, 4) columns t, x, y, p; got shape {arr.shape}")
    span = _span(path, arr[:, 0])
    for i in range(0, arr.shape[0], chunk):
        block = np.asarray(arr[i:i + chunk])
        x, y = _coords(path, block[:, 1], block[:, 2])
        yield x, y, _to_us(path, block[:, 0], span), _polarity(path, block[:, 3])


# --- text --------------------------------------------------------------------------------

def _text(path: Path, chunk: int) -> Iterator[Arrays]:
    seconds: bool | None = None
    line_no = 0
    first = True
    with open(path, "rb") as f:
        for body in _line_blocks(f, max(1 << 20, chunk * 24)):
            if first:
                first = False
                head, _, tail = body.partition(b"\n")
                tokens = head.split()
                if len(tokens) == 2 and all(t.isdigit() for t in tokens):  # "W H" size line
                    body = tail
                    line_no += 1
            if b"#" in body:
                body = b"\n".join(ln for ln in body.split(b"\n") if not ln.lstrip().startswith(b"#"))
            if not body.strip():
                continue
            if seconds is None:
                tok = body.split(None, 1)[0]
                seconds = b"." in tok or b"e" in tok.lower()
            rows = count_rows(path, body, 4, line_no + 1)
            try:
                flat = np.array(body.split(), dtype=np.float64)
            except ValueError:
                raise InputError(path, f"non-numeric text after line {line_no}; expected 't x y p' per line") from None
            table = flat.reshape(rows, 4)
            line_no += body.count(b"\n")
            x, y = _coords(path, table[:, 1], table[:, 2])
            yield x, y, _to_us(path, table[:, 0], seconds=seconds), _polarity(path, table[:, 3])


def _line_blocks(f, block_bytes: int) -> Iterator[bytes]:
    """Read a text file in blocks that end on a line boundary."""
    rest = b""
    while True:
        data = f.read(block_bytes)
        if not data:
            if rest.strip():
                yield rest
            return
        data = rest + data
        cut = data.rfind(b"\n") + 1
        if cut == 0:
            rest = data
            continue
        yield data[:cut]
        rest = data[cut:]
