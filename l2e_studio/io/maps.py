"""The 2D map a scene's lidar is scored against: an accumulated event map or a camera frame.

:func:`load_map` returns a float32 (H, W) array and its kind:

* ``"events"`` -- an accumulated event map: raw per-pixel counts (the reference code's uint8
  PNGs, our own 8/16-bit PNG/TIFF maps, a 2D ``.npy``), or a raw event recording (any
  :data:`~l2e_studio.io.events.EVENT_SUFFIXES` file) accumulated on the fly per the paper
  (count events per pixel over a window, clip to [0, 127]) and cached next to the file as
  ``<file>.l2ecache.npz`` (or in the user cache dir when that folder is read-only);
* ``"image"`` -- a camera frame, converted to grey (the MI method came from lidar-to-camera
  calibration, so an ordinary camera works the same way).

How the kind is decided when ``kind`` is not given: raw event files are ``"events"``; JPEGs
and colour images (3 or 4 channels) are ``"image"``; a single-channel image is ``"events"``
when its file name or one of its two parent folders contains "event" (the reference layout
``DIR/event/<stem>.png``) and its folder is not ``image/``/``images/``, ``"image"`` otherwise. Values are returned unclipped and
unsmoothed: :func:`l2e_studio.objective.prepare_map` does that.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..atomic import atomic_write_bytes
from ..errors import InputError
from ..limits import MAX_IMAGE_SIDE
from .safe_load import load_npy

#: Image suffixes read as maps. Raw event suffixes (``EVENT_SUFFIXES``) are accepted as well.
IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm", ".exr")
MAP_KINDS = ("events", "image")
#: What the objective clips each kind of map to: the paper's [0, 127] for event counts (a few
#: pixels fire wildly), the 8-bit range for camera frames.
MAP_CLIP = {"events": 127.0, "image": 255.0}
#: The clip is meant for a few wild pixels: when more than this share of a map's non-zero pixels
#: lies above it (a 16-bit map, a long window), the clipped map would be little more than a mask
#: of where events fired, so it is rescaled. (Maps that fit, e.g. the synthetic ones, have 1-10 %.)
MAX_CLIPPED_SHARE = 0.5
#: After rescaling, this share of the non-zero pixels lies above the clip (the "few wild pixels").
RESCALED_CLIPPED_SHARE = 0.01


def _event_suffixes() -> tuple[str, ...]:
    from .events import EVENT_SUFFIXES

    return EVENT_SUFFIXES


#: Every suffix :func:`load_map` reads: images first, then raw event recordings.
MAP_SUFFIXES: tuple[str, ...] = IMAGE_SUFFIXES + tuple(s for s in _event_suffixes() if s not in IMAGE_SUFFIXES)


def map_suffix(path: str | Path) -> str | None:
    """The entry of :data:`MAP_SUFFIXES` that ``path`` ends with (longest match), or None."""
    name = Path(path).name.lower()
    matches = [s for s in MAP_SUFFIXES if name.endswith(s)]
    return max(matches, key=len) if matches else None


def is_event_recording(path: str | Path) -> bool:
    """Whether :func:`load_map` accumulates ``path`` from raw events (rather than reading an image
    or a 2D ``.npy`` map)."""
    path = Path(path)
    suffix = map_suffix(path)
    if suffix is None or suffix in IMAGE_SUFFIXES:
        return False
    return not (suffix == ".npy" and path.is_file() and is_map_npy(path))


def guess_kind(path: str | Path, channels: int = 1) -> str:
    """The map kind of a file by the rules in the module docstring."""
    path = Path(path)
    suffix = map_suffix(path)
    if suffix is not None and suffix not in IMAGE_SUFFIXES and suffix != ".npy":
        return "events"
    if suffix in (".jpg", ".jpeg") or channels >= 3:
        return "image"
    if path.parent.name.lower() in ("image", "images"):  # the map folder says so (a data set may be named "..._event")
        return "image"
    names = [path.name, path.parent.name, path.parent.parent.name]
    return "events" if any("event" in n.lower() for n in names) else "image"


def looks_like_photo(image: np.ndarray) -> bool:
    """Whether a map's content is a camera image rather than accumulated events: almost no
    empty pixels, a share of values past the events' clip of 127, and a photograph's many grey
    levels. (Event maps leave most pixels at zero; measured on the real recordings in
    ../shared/realdata: photos 0-0.004 % zeros and 28-73 % above 127, event maps 63-84 % zeros.)"""
    m = np.asarray(image)
    if m.size == 0:
        return False
    zeros = float(np.count_nonzero(m == 0)) / m.size
    bright = float(np.count_nonzero(m > 127)) / m.size
    levels = np.unique(np.rint(m[:: max(1, m.shape[0] // 200), :: max(1, m.shape[1] // 200)])).size
    return zeros < 0.05 and bright > 0.01 and levels >= 100


def load_map(
    path: str | Path,
    width: int | None = None,
    height: int | None = None,
    kind: str | None = None,
    window_s: float = 3.0,
    start_s: float | None = None,
    hot_pixel_sigma: float | None = None,
    cache: bool = True,
) -> tuple[np.ndarray, str]:
    """Read a map as float32 (H, W) and its kind ("events" or "image").

    ``width``/``height``, when given, are the camera's image size: a map of another size is an
    error. For raw event files they also set the sensor size when the file does not say it.
    ``window_s``, ``start_s`` and ``hot_pixel_sigma`` are passed to the accumulation.
    """
    path = Path(path)
    if kind is not None and kind not in MAP_KINDS:
        raise ValueError(f"kind must be one of {MAP_KINDS}, got {kind!r}")
    suffix = map_suffix(path)
    if suffix is None:
        raise InputError(path, f"unknown map format; expected one of {', '.join(MAP_SUFFIXES)}")
    if not path.is_file():
        raise InputError(path, "map file not found")
    if suffix in IMAGE_SUFFIXES:
        image, channels = _read_image(path, width, height)
    elif not is_event_recording(path):
        image, channels = _read_npy_map(path), 1
    else:
        from .events import accumulate_events_cached

        image = accumulate_events_cached(
            path, window_s=window_s, start_s=start_s, hot_pixel_sigma=hot_pixel_sigma,
            width=width, height=height, use_cache=cache,
        ).astype(np.float32)
        channels = 1
        kind = kind or "events"
    if kind is None:
        kind = guess_kind(path, channels)
        if kind == "events" and looks_like_photo(image):
            kind = "image"
    _check_size(path, image, width, height)
    check_values(path, image)
    return image, kind


def check_values(path: Path, image: np.ndarray) -> None:
    """Refuse a map with NaN, infinite or negative values: neither event counts nor grey levels
    can be negative, and such a map is damaged or something else (a depth or flow image...)."""
    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        raise InputError(path, f"{bad} of {image.size} map values are NaN or infinite; expected event counts or grey levels")
    negative = int(np.count_nonzero(image < 0))
    if negative:
        raise InputError(path, f"{negative} of {image.size} map values are negative (down to {float(image.min()):.4g}); "
                               "expected event counts or grey levels, which are >= 0")


def fit_to_clip(image: np.ndarray, kind: str) -> tuple[np.ndarray, float]:
    """``(map, scale)``: the map multiplied by ``scale`` (1: unchanged) so that at most
    :data:`RESCALED_CLIPPED_SHARE` of its non-zero pixels lie above the clip of its ``kind``,
    when more than :data:`MAX_CLIPPED_SHARE` did (clipping would flatten the map: a 16-bit map
    whose counts are all above 127 carries no information after the clip)."""
    clip = MAP_CLIP[kind]
    firing = image[image > 0]
    if firing.size == 0 or np.count_nonzero(firing > clip) <= MAX_CLIPPED_SHARE * firing.size:
        return image, 1.0
    scale = clip / float(np.percentile(firing, 100 * (1 - RESCALED_CLIPPED_SHARE)))
    return (image * np.float32(scale)).astype(np.float32), scale


def png_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG's IHDR chunk, without decoding it; None for other formats."""
    if len(data) < 24 or data[:8] != b"\x89PNG\r\n\x1a\n" or data[12:16] != b"IHDR":
        return None
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def _read_image(path: Path, width: int | None = None, height: int | None = None) -> tuple[np.ndarray, int]:
    data = np.fromfile(path, dtype=np.uint8)
    if data.size == 0:
        raise InputError(path, "the image file is empty")
    declared = png_size(data[:24].tobytes())
    if declared is not None:  # refuse before decoding: a small PNG can declare gigapixels
        w, h = declared
        if not (0 < w <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE):
            raise InputError(path, f"the PNG declares {w}x{h} pixels; at most {MAX_IMAGE_SIDE} a side are read")
        _check_dims(path, w, h, width, height)
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(path, "cannot decode the image (corrupt, truncated or not an image)")
    if image.size == 0:
        raise InputError(path, "the image has no pixels")
    channels = 1 if image.ndim == 2 else image.shape[2]
    img = image.astype(np.float32)
    if channels == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    elif channels == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY)
    elif channels == 2:  # grey + alpha
        img = img[:, :, 0]
    elif channels != 1:
        raise InputError(path, f"image has {channels} channels; expected 1, 3 or 4")
    return np.ascontiguousarray(img, dtype=np.float32), channels


def is_map_npy(path: Path) -> bool:
    """Whether a .npy holds a 2D map (plain, more than 8 columns) rather than an event table."""
    arr = load_npy(path, mmap=True)
    return arr.dtype.names is None and arr.ndim == 2 and arr.shape[1] > 8


def _read_npy_map(path: Path) -> np.ndarray:
    arr = load_npy(path)
    if not np.issubdtype(arr.dtype, np.number):
        raise InputError(path, f"map array has non-numeric dtype {arr.dtype}")
    if arr.ndim != 2 or arr.size == 0:
        raise InputError(path, f"a map array must be 2-D, got shape {arr.shape}")
    return arr.astype(np.float32)


def _check_size(path: Path, image: np.ndarray, width: int | None, height: int | None) -> None:
    h, w = image.shape[:2]
    _check_dims(path, w, h, width, height)


def _check_dims(path: Path, w: int, h: int, width: int | None, height: int | None) -> None:
    """A ``w`` x ``h`` map must match the camera's ``width`` x ``height`` where they are known."""
    if (width is not None and w != int(width)) or (height is not None and h != int(height)):
        want = f"{width if width is not None else '?'}x{height if height is not None else '?'}"
        raise InputError(path, f"map is {w}x{h}, camera expects {want}")


def write_map_png(path: str | Path, event_map: np.ndarray) -> Path:
    """Write an accumulated event map as an 8-bit PNG (values clipped to [0, 255])."""
    path = Path(path)
    img = np.clip(np.rint(np.asarray(event_map, dtype=np.float64)), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise OSError(f"cannot encode {path} as PNG")
    atomic_write_bytes(path, buf.tobytes())
    return path
