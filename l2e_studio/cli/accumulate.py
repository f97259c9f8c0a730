"""``l2e-studio accumulate DIR``: build accumulated event maps from raw event recordings.

Layout:

* raw recordings in ``DIR/events_raw/`` (any of ``EVENT_SUFFIXES``: .raw, .dat, .aedat4, .h5,
  .npz, .npy, .txt) -> ``DIR/event/<stem>.png``, the reference code's layout, which pairs
  with ``DIR/lidar/<stem>.*``. An existing PNG is kept unless ``--force``.
* raw recordings already in ``DIR/event/`` are read directly by the workbench (a PNG beside
  them would pair twice by stem), so for those the command only fills the map cache
  (``<file>.l2ecache.npz``) so that the first load is instant.

Per the paper: every event counts regardless of polarity, over ``--window`` seconds (default
3) from ``--start`` seconds into the recording, clipped to [0, 127]; ``--hot-pixels`` zeroes
pixels firing far above the rest. The sensor size comes from the file, ``--size WxH``, or
``DIR/camera.yaml`` when the file does not say.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InputError

NAME = "accumulate"
HELP = ("Build accumulated event maps (count per pixel over a window, clip to 127) from raw event files: "
        "DIR/events_raw/<stem>.* -> DIR/event/<stem>.png; raw files in DIR/event/ get their map cached")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folder", type=Path, metavar="DIR", help="scene folder (with events_raw/ and/or event/)")
    parser.add_argument("--window", type=float, default=3.0, metavar="S", help="accumulation window in seconds (default 3.0)")
    parser.add_argument("--start", type=float, default=None, metavar="S",
                        help="window start, seconds after the first event (default 0)")
    parser.add_argument("--hot-pixels", type=float, nargs="?", const=6.0, default=None, metavar="SIGMA",
                        help="zero pixels above median + SIGMA robust deviations of the firing pixels (default SIGMA 6)")
    parser.add_argument("--size", default=None, metavar="WxH", help="sensor size when the files do not state it")
    parser.add_argument("--force", action="store_true", help="overwrite existing PNG maps")


def find_raw_files(folder: Path) -> tuple[list[Path], list[Path]]:
    """(recordings in events_raw/, recordings in event/), sorted by name."""
    from ..io.events import CACHE_SUFFIX, event_suffix
    from ..io.maps import IMAGE_SUFFIXES

    def raw_in(d: Path) -> list[Path]:
        if not d.is_dir():
            return []
        return sorted(p for p in d.iterdir() if p.is_file() and event_suffix(p) is not None
                      and not p.name.endswith(CACHE_SUFFIX) and p.suffix.lower() not in IMAGE_SUFFIXES
                      and not _is_map_npy(p))
    return raw_in(folder / "events_raw"), raw_in(folder / "event")


def _is_map_npy(path: Path) -> bool:
    """A 2D map saved as .npy (the workbench reads it as a map), not raw events."""
    from ..io.maps import is_map_npy

    if path.suffix.lower() != ".npy":
        return False
    try:
        return is_map_npy(path)
    except InputError:  # unreadable: left to the accumulation to report
        return False


def _size(args: argparse.Namespace, folder: Path) -> tuple[int | None, int | None]:
    from ..io.events import parse_size

    if args.size:
        return parse_size(args.size)
    from ..io.cameras import load_rig

    for name in ("camera.yaml", "camera.yml"):
        if (folder / name).is_file():
            rig = load_rig(folder / name)
            return rig.width, rig.height
    return None, None


def _stem(path: Path) -> str:
    from ..io.events import event_suffix

    suffix = event_suffix(path) or path.suffix
    return path.name[: -len(suffix)]


def check_options(args: argparse.Namespace) -> None:
    """Refuse NaN, infinite or absurd windows, starts and hot-pixel sigmas with one line."""
    from ..limits import MAX_WINDOW_S, require_range

    require_range("--window", args.window, 0.0, MAX_WINDOW_S, low_inclusive=False)
    require_range("--start", args.start, 0.0, MAX_WINDOW_S)
    require_range("--hot-pixels", args.hot_pixels, 0.0, 1000.0, low_inclusive=False)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import Progress

    from ..io.events import EVENT_SUFFIXES, accumulate_events_cached
    from ..io.maps import write_map_png

    check_options(args)
    folder: Path = args.folder
    if not folder.is_dir():
        raise InputError(folder, "scene folder not found")
    to_png, in_place = find_raw_files(folder)
    if not to_png and not in_place:
        raise InputError(folder, f"no raw event files in events_raw/ or event/ ({', '.join(EVENT_SUFFIXES)})")
    width, height = _size(args, folder)
    console = Console(stderr=True)
    written = cached = skipped = 0
    failures: list[InputError] = []
    with Progress(console=console, transient=True) as progress:
        task = progress.add_task("accumulating", total=len(to_png) + len(in_place))
        for path in to_png + in_place:
            progress.update(task, description=path.name)
            out = folder / "event" / f"{_stem(path)}.png"
            try:
                if path in to_png and out.exists() and not args.force:
                    skipped += 1
                    console.print(f"kept existing {out} (use --force to rebuild)", highlight=False)
                else:
                    image = accumulate_events_cached(path, window_s=args.window, start_s=args.start,
                                                     hot_pixel_sigma=args.hot_pixels, width=width, height=height)
                    if path in to_png:
                        write_map_png(out, image)
                        written += 1
                    else:
                        cached += 1
                    console.print(f"{path.name}: {image.shape[1]}x{image.shape[0]}, "
                                  f"{int((image > 0).sum())} firing pixels, max {image.max():.0f}", highlight=False)
            except InputError as exc:
                failures.append(exc)
            progress.advance(task)
    if failures and not (written or cached or skipped):
        more = f" (and {len(failures) - 1} more file(s) failed)" if len(failures) > 1 else ""
        raise InputError(None, f"{failures[0]}{more}")
    for exc in failures:
        print(f"warning: skipped {exc}", file=sys.stderr)
    print(f"{written} map(s) written to {folder / 'event'}, {cached} cached in place, "
          f"{skipped} kept, {len(failures)} failed")
    return 0
