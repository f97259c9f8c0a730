"""Raw event recordings -> the paper's accumulated event map.

The map (paper, "Event Camera-Lidar Extrinsic Calibration"): count every event per pixel,
regardless of polarity, over a time window (default 3 s) of a static scene, and clip the
counts to [0, 127]. Recordings are streamed in chunks, so memory stays bounded (a few chunk
buffers plus one int64 count image) whatever the file size.

Formats (by suffix, :data:`EVENT_SUFFIXES`):

* Prophesee ``.raw`` (EVT 2.0, EVT 3.0; from the ``%`` header) and ``.dat`` -- our own
  vectorised decoders, :mod:`l2e_studio.io.event_prophesee`;
* iniVation ``.aedat4`` -- via the ``aedat`` package (Rust decoder);
* HDF5 ``.h5``/``.hdf5`` -- ``events/{x,y,t,p}`` as in DSEC (t in us, plus an optional
  root ``t_offset``), root-level ``x,y,t,p``, or a compound ``events`` / ``CD/events`` table;
* ``.npz`` (arrays ``x,y,t,p`` or a structured/(N,4) ``events`` array) and ``.npy``
  (structured with fields x, y, t, p, or (N,4) columns t, x, y, p);
* text ``.txt`` -- ``t x y p`` one event a line (the Event Camera Dataset layout); times with
  a decimal point are seconds, integers are microseconds; an optional first line ``W H``
  gives the sensor size.

Times are normalised to integer microseconds. For arrays with float times: seconds when the
span of the recording is under 10^4 (i.e. < 2.8 h in seconds), microseconds otherwise.
"""

from __future__ import annotations

import hashlib
import io
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ..cachedir import user_cache_dir
from ..atomic import atomic_write_bytes
from ..errors import InputError
from ..limits import MAX_BACKWARD_STEP_US, MAX_EVENT_SENSOR_SIDE
from . import event_prophesee as prophesee
from .safe_load import NPZ_ERRORS

#: Suffixes of raw event recordings (``.txt`` only inside an event folder; ``.npy`` may also be a 2D map).
EVENT_SUFFIXES: tuple[str, ...] = (".raw", ".dat", ".aedat4", ".h5", ".hdf5", ".npz", ".npy", ".txt")

DEFAULT_CHUNK = 2_000_000
#: More than this share of a window's events outside the sensor is an error, not a silent crop.
MAX_OUTSIDE_FRACTION = 0.001
CACHE_SUFFIX = ".l2ecache.npz"
_CACHE_VERSION = 1


@dataclass(frozen=True)
class Accumulation:
    """How a raw recording becomes a map: count events over ``[t0 + start_s, + window_s)``
    (``t0`` the first event), optionally zero hot pixels (``hot_pixel_sigma``; None = off)."""

    window_s: float = 3.0
    start_s: float = 0.0
    hot_pixel_sigma: float | None = None

    def __post_init__(self) -> None:
        if not self.window_s > 0:
            raise ValueError(f"the window must be positive, got {self.window_s:g} s")
        if not self.start_s >= 0:
            raise ValueError(f"the start must be 0 s or later, got {self.start_s:g} s")
        if self.hot_pixel_sigma is not None and not self.hot_pixel_sigma > 0:
            raise ValueError(f"the hot-pixel sigma must be positive (or off), got {self.hot_pixel_sigma:g}")

    def to_dict(self) -> dict:
        """Plain types, as result files record them."""
        return {"window_s": float(self.window_s), "start_s": float(self.start_s),
                "hot_pixel_sigma": None if self.hot_pixel_sigma is None else float(self.hot_pixel_sigma)}

    def describe(self) -> str:
        """One line, e.g. ``3 s from 0 s, hot pixels off``."""
        hot = "off" if self.hot_pixel_sigma is None else f"σ {self.hot_pixel_sigma:g}"
        return f"{self.window_s:g} s from {self.start_s:g} s, hot pixels {hot}"


@dataclass
class EventChunk:
    """A run of events: x, y (uint16), t_us (int64, microseconds), p (uint8, 0/1)."""

    x: np.ndarray
    y: np.ndarray
    t_us: np.ndarray
    p: np.ndarray

    def __len__(self) -> int:
        return int(self.t_us.size)


def event_suffix(path: str | Path) -> str | None:
    name = Path(path).name.lower()
    return next((s for s in EVENT_SUFFIXES if name.endswith(s)), None)


def iter_events(path: str | Path, chunk_size: int = DEFAULT_CHUNK) -> Iterator[EventChunk]:
    """Stream a recording as :class:`EventChunk` s of at most about ``chunk_size`` events."""
    path = Path(path)
    suffix = event_suffix(path)
    if suffix is None:
        raise InputError(path, f"unknown event format; expected one of {', '.join(EVENT_SUFFIXES)}")
    if not path.is_file():
        raise InputError(path, "event file not found")
    if path.stat().st_size == 0:
        raise InputError(path, "the event file is empty")
    try:
        t_max, seen = None, 0
        for x, y, t, p in _decoder(path, suffix, chunk_size):
            if not len(x) == len(y) == len(t) == len(p):
                raise InputError(path, f"a chunk holds {len(x)} x, {len(y)} y, {len(t)} times and {len(p)} polarities; "
                                       "they must be as many")
            if len(t):
                t_max = _check_time_order(path, t, t_max, seen)
                seen += len(t)
                yield EventChunk(x, y, t, p)
    except InputError:
        raise
    except (*NPZ_ERRORS, RuntimeError) as exc:
        raise InputError(path, f"cannot decode {suffix} events ({str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__})") from exc


def _check_time_order(path: Path, t: np.ndarray, t_max: int | None, seen: int) -> int:
    """Refuse times that step back more than :data:`MAX_BACKWARD_STEP_US` (a window cut from the
    first event would silently drop the rest); returns the running maximum."""
    running = np.maximum.accumulate(t if t_max is None else np.maximum(t, t_max))
    back = running - t
    worst = int(np.argmax(back))
    if back[worst] > MAX_BACKWARD_STEP_US:
        raise InputError(path, f"event times run backwards at event {seen + worst} ({int(t[worst])} us after "
                               f"{int(running[worst])} us): the recording is not time-ordered; sort it by time first")
    return int(running[-1])


def sensor_size(path: str | Path) -> tuple[int, int] | None:
    """(width, height) as the file states it, or None when it does not say; an absurd size is an error."""
    path = Path(path)
    suffix = event_suffix(path)
    if suffix is None or not path.is_file():
        return None
    if suffix in (".raw", ".dat"):
        size = prophesee.read_header(path).size
    else:
        from . import event_formats

        size = event_formats.sensor_size(path, suffix)
    if size is not None and not all(0 < v <= MAX_EVENT_SENSOR_SIDE for v in size):
        raise InputError(path, f"the file states a {size[0]}x{size[1]} sensor; event sensors are at most "
                               f"{MAX_EVENT_SENSOR_SIDE} pixels a side")
    return size


def _decoder(path: Path, suffix: str, chunk_size: int):
    if suffix in (".raw", ".dat"):
        header = prophesee.read_header(path)
        if suffix == ".dat":
            return prophesee.decode_dat(path, header, chunk_size)
        if header.encoding == "evt2":
            return prophesee.decode_evt2(path, header, chunk_size)
        if header.encoding == "evt3":
            return prophesee.decode_evt3(path, header, chunk_size)
        if header.encoding is None:
            raise InputError(path, "the header names no event encoding (no '% evt 2.0|3.0' or '% format EVT..' line)")
        raise InputError(path, f"unsupported event encoding {header.encoding!r}; EVT 2.0 and EVT 3.0 are read")
    from . import event_formats

    return event_formats.decoder(path, suffix, chunk_size)


@dataclass
class EventStats:
    """Counts and ranges of a whole recording (for checks and the CLI)."""

    count: int
    t_first_us: int
    t_last_us: int
    x_min: int
    x_max: int
    y_min: int
    y_max: int
    on: int

    @property
    def duration_s(self) -> float:
        return (self.t_last_us - self.t_first_us) * 1e-6


def event_stats(path: str | Path, chunk_size: int = DEFAULT_CHUNK) -> EventStats:
    """Stream the whole recording once and summarise it."""
    n = on = 0
    t0 = t1 = None
    xr = [np.iinfo(np.int64).max, -1]
    yr = [np.iinfo(np.int64).max, -1]
    for c in iter_events(path, chunk_size):
        n += len(c)
        on += int(np.count_nonzero(c.p))
        t0 = int(c.t_us.min()) if t0 is None else min(t0, int(c.t_us.min()))
        t1 = int(c.t_us.max()) if t1 is None else max(t1, int(c.t_us.max()))
        xr = [min(xr[0], int(c.x.min())), max(xr[1], int(c.x.max()))]
        yr = [min(yr[0], int(c.y.min())), max(yr[1], int(c.y.max()))]
    if n == 0:
        raise InputError(path, "the recording holds no events")
    return EventStats(n, t0, t1, xr[0], xr[1], yr[0], yr[1], on)  # type: ignore[arg-type]


def accumulate_events(
    path: str | Path,
    window_s: float = 3.0,
    start_s: float | None = None,
    hot_pixel_sigma: float | None = None,
    width: int | None = None,
    height: int | None = None,
    clip: float | None = 127.0,
    chunk_size: int = DEFAULT_CHUNK,
) -> np.ndarray:
    """Count events per pixel over ``[t0 + start_s, t0 + start_s + window_s)``; float32 (H, W).

    ``t0`` is the first event's time, so ``start_s`` is seconds into the recording (None = 0).
    The size is ``width`` x ``height`` when given, else the file's sensor size, else the
    largest coordinates seen + 1. Events outside the size are dropped. With
    ``hot_pixel_sigma``, pixels whose count exceeds median + sigma * 1.4826 * MAD of the
    firing pixels are set to 0 (hot pixels fire regardless of the scene). Then counts are
    clipped to [0, ``clip``] (the paper's 127; None keeps raw counts).
    """
    path = Path(path)
    if window_s <= 0:
        raise ValueError(f"window_s must be positive, got {window_s}")
    declared = sensor_size(path)
    size = (int(width), int(height)) if width is not None and height is not None else declared
    if declared is not None and size != declared:
        raise InputError(path, f"the file states a {declared[0]}x{declared[1]} sensor but the camera is "
                               f"{size[0]}x{size[1]}; events would be cropped or misplaced")
    counter = _Counter(size, path)
    begin = end = None
    for c in iter_events(path, chunk_size):
        if begin is None:
            begin = int(c.t_us[0]) + int(round((start_s or 0.0) * 1e6))
            end = begin + int(round(window_s * 1e6))
        if not counter.add_window(c.x, c.y, c.t_us, begin, end) and c.t_us.min() >= end:
            break  # recordings are time-ordered: nothing later falls inside
    if counter.total == 0:
        raise InputError(path, _empty_window_message(begin, start_s, window_s))
    if counter.outside > MAX_OUTSIDE_FRACTION * (counter.total + counter.outside):
        W, H = counter.grid.shape[1], counter.grid.shape[0]
        raise InputError(path, f"{counter.outside} of {counter.total + counter.outside} events in the window fall "
                               f"outside the {W}x{H} sensor; wrong --size or camera, or damaged data")
    image = counter.grid.astype(np.float64)
    if hot_pixel_sigma is not None:
        image = suppress_hot_pixels(image, hot_pixel_sigma)
    if clip is not None:
        image = np.clip(image, 0.0, clip)
    return image.astype(np.float32)


class _Counter:
    """Per-pixel event counts; a fixed size drops events outside it, no size grows to fit."""

    def __init__(self, size: tuple[int, int] | None, path: Path | None = None) -> None:
        self.fixed = size is not None
        self.path = path
        w, h = size if size is not None else (0, 0)
        self.grid = np.zeros((h, w), np.int64)
        self.total = 0
        self.outside = 0  # events dropped outside a fixed size

    def add_window(self, x: np.ndarray, y: np.ndarray, t: np.ndarray, begin: int, end: int) -> int:
        """Count the events with ``begin <= t < end``; returns how many fell in the window."""
        if self.fixed and x.dtype.kind in "ui" and y.dtype.kind in "ui" and t.dtype == np.int64:
            from ..compiled import count_events  # one compiled pass

            inside, outside = count_events(x, y, t, begin, end, self.grid)
            self.total += inside
            self.outside += outside
            return inside + outside
        sel = (t >= begin) & (t < end)
        if sel.any():
            self.add(x[sel], y[sel])
        return int(np.count_nonzero(sel))

    def add(self, x: np.ndarray, y: np.ndarray) -> None:
        x = x.astype(np.int64)
        y = y.astype(np.int64)
        H, W = self.grid.shape
        if self.fixed:
            inside = (x < W) & (y < H)
            self.outside += int(x.size - np.count_nonzero(inside))
            x, y = x[inside], y[inside]
        else:
            h_new, w_new = max(H, int(y.max()) + 1), max(W, int(x.max()) + 1)
            if max(h_new, w_new) > MAX_EVENT_SENSOR_SIDE:
                raise InputError(self.path, f"events at x={int(x.max())}, y={int(y.max())} and no sensor size in the "
                                            f"file: beyond any event sensor ({MAX_EVENT_SENSOR_SIDE} px); pass --size WxH")
            if (h_new, w_new) != (H, W):
                grown = np.zeros((h_new, w_new), np.int64)
                grown[:H, :W] = self.grid
                self.grid, (H, W) = grown, (h_new, w_new)
        if x.size:
            self.grid += np.bincount(y * W + x, minlength=H * W).reshape(H, W)
            self.total += int(x.size)


def _empty_window_message(begin, start_s, window_s) -> str:
    if begin is None:
        return "the recording holds no events"
    return f"no events in the window {start_s or 0.0:g} s + {window_s:g} s (is the start past the end?)"


def suppress_hot_pixels(counts: np.ndarray, sigma: float) -> np.ndarray:
    """Zero pixels firing far above the others: count > median + sigma * 1.4826 * MAD (of firing pixels)."""
    out = np.array(counts, dtype=np.float64)
    firing = out[out > 0]
    if firing.size < 10:
        return out
    med = float(np.median(firing))
    mad = float(np.median(np.abs(firing - med))) * 1.4826
    limit = med + sigma * max(mad, 1.0)
    out[out > limit] = 0.0
    return out


# --- cache ---------------------------------------------------------------------------------

def _cache_key(path: Path, **params) -> str:
    st = path.stat()
    parts = [str(_CACHE_VERSION), str(st.st_size), str(st.st_mtime_ns)] + [f"{k}={params[k]!r}" for k in sorted(params)]
    return hashlib.sha1("|".join(parts).encode()).hexdigest()


def cache_paths(path: Path) -> list[Path]:
    """Where a map built from ``path`` is cached: the user cache folder (written), then beside
    the file (read only: where earlier versions wrote it; the data folder is never written)."""
    user = user_cache_dir("event_maps")
    digest = hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:16]
    return [user / f"{path.name}.{digest}{CACHE_SUFFIX}", path.with_name(path.name + CACHE_SUFFIX)]


def accumulate_with(
    path: str | Path, settings: Accumulation, width: int | None = None, height: int | None = None, use_cache: bool = True,
) -> np.ndarray:
    """:func:`accumulate_events_cached` with the parameters of ``settings``."""
    return accumulate_events_cached(path, settings.window_s, settings.start_s, settings.hot_pixel_sigma,
                                    width, height, use_cache)


def accumulate_events_cached(
    path: str | Path,
    window_s: float = 3.0,
    start_s: float | None = None,
    hot_pixel_sigma: float | None = None,
    width: int | None = None,
    height: int | None = None,
    use_cache: bool = True,
) -> np.ndarray:
    """:func:`accumulate_events` with a cache keyed by (file size, mtime, window, start, ...)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "event file not found")
    hot = None if hot_pixel_sigma is None else float(hot_pixel_sigma)
    params = dict(window_s=float(window_s), start_s=float(start_s or 0.0), hot=hot, width=width, height=height)
    key = _cache_key(path, **params)
    if use_cache:
        for cpath in cache_paths(path):
            cached = _read_cache(cpath, key)
            if cached is not None:
                return cached
    image = accumulate_events(path, window_s, start_s, hot_pixel_sigma, width, height)
    if use_cache:
        _write_cache(cache_paths(path)[0], key, image)  # best effort
    return image


def _read_cache(cpath: Path, key: str) -> np.ndarray | None:
    try:
        with np.load(cpath, allow_pickle=False) as z:
            if str(z["key"]) != key:
                return None
            return z["map"].astype(np.float32)
    except NPZ_ERRORS:  # a damaged cache entry is rebuilt
        return None


def _write_cache(cpath: Path, key: str, image: np.ndarray) -> bool:
    buf = io.BytesIO()
    np.savez_compressed(buf, key=np.array(key), map=image.astype(np.float32))
    try:
        atomic_write_bytes(cpath, buf.getvalue())
        return True
    except OSError:
        return False


def parse_size(text: str) -> tuple[int, int]:
    """``"1280x720"`` -> (1280, 720); :class:`InputError` (a ValueError) naming the text otherwise."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX, ]\s*(\d+)\s*", text)
    if not m:
        raise InputError(None, f"--size expects a size like 1280x720, got {text!r}")
    w, h = int(m.group(1)), int(m.group(2))
    if not (0 < w <= MAX_EVENT_SENSOR_SIDE and 0 < h <= MAX_EVENT_SENSOR_SIDE):
        raise InputError(None, f"--size must be 1..{MAX_EVENT_SENSOR_SIDE} pixels a side, got {text!r}")
    return w, h
