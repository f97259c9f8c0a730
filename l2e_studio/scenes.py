"""Scene folders: discovery, pairing and loading.

Layout (the reference code's, extended to every format :mod:`l2e_studio.io` reads)::

    DIR/event/<stem>.png|.raw|.h5|...   accumulated event map, raw events, or a camera image
    DIR/lidar/<stem>.txt|.pcd|.bin|...  lidar scan
    DIR/camera.yaml                     intrinsics + seed (ours), or
    DIR/config/config.json              intrinsics + seed (the reference format, key "cam")

Maps and scans are paired by file stem. Files without a partner are reported in
``SceneSet.unpaired``; a scene whose files cannot be read becomes a :class:`SceneFailure`
while the others load. Parsed scans are cached in the user's cache folder (:mod:`~l2e_studio.cachedir`) (keyed by file size and
modification time) so the second load of a large folder is fast.
"""

from __future__ import annotations

import hashlib
import io
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from .atomic import atomic_write_bytes
from .cachedir import folder_key, user_cache_dir
from .camera import CameraModel
from .errors import InputError
from .geometry import Extrinsic
from .io.cameras import load_rig, load_seed
from .io.events import EVENT_SUFFIXES, Accumulation, accumulate_with
from .io.lidar import LIDAR_SUFFIXES, load_lidar
from .io.maps import (MAP_CLIP, MAP_SUFFIXES, MAX_CLIPPED_SHARE, RESCALED_CLIPPED_SHARE, fit_to_clip, guess_kind,
                      is_event_recording, load_map)

MAP_DIRS = ("event", "events", "image", "images")
LIDAR_DIRS = ("lidar", "pointcloud", "pointclouds")
RIG_FILES = ("camera.yaml", "camera.yml", "config/config.json", "config.json")
#: Bumped when the scan readers refuse more: a scan cached by an older version is read again.
SCAN_CACHE_VERSION = 2
CACHE_DIR = ".l2e_cache"  # where earlier versions cached scans (inside the data folder); no longer written


@dataclass
class Scene:
    """One static scene: a lidar scan and the event map (or image) seen at the same time."""

    name: str
    points: np.ndarray  # (N, 3) float32, lidar frame
    intensity: np.ndarray  # (N,) float32, 0..255
    event_map: np.ndarray  # (H, W) float32, raw counts or grey image, unclipped, unsmoothed
    map_kind: str = "events"  # "events" | "image"
    lidar_path: Path | None = None
    map_path: Path | None = None
    accumulation: Accumulation | None = None  # how the map was built from raw events; None: read as an image
    map_scale: float = 1.0  # the file's values were multiplied by this to fit the clip (:func:`~.io.maps.fit_to_clip`)

    def map_record(self) -> dict:
        """How this scene's map was made, as result files record it (``accumulation`` is None
        for a map read as an image)."""
        return {"file": None if self.map_path is None else str(self.map_path), "kind": self.map_kind,
                "accumulation": None if self.accumulation is None else self.accumulation.to_dict()}


@dataclass
class SceneFailure:
    """A scene that could not be loaded, and why (one line naming the file)."""

    name: str
    error: str


@dataclass
class SceneSet:
    """What a scene folder holds: the camera, the seed, and the scenes that loaded."""

    root: Path
    camera: CameraModel
    seed: Extrinsic
    scenes: list[Scene]
    failures: list[SceneFailure] = field(default_factory=list)
    unpaired: list[str] = field(default_factory=list)
    seed_source: str = ""
    camera_source: str = ""
    notes: list[str] = field(default_factory=list)  # one line each, worth telling the user

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.scenes]


def find_scene_files(folder: Path) -> tuple[dict[str, tuple[Path, Path]], list[str], dict[str, str]]:
    """Pair map files with lidar files by stem: ``({stem: (map, lidar)}, unpaired messages,
    {stem: problem})``; a stem with two map files or two scans is ambiguous, never paired."""
    maps, map_twins = _by_stem(_first_dir(folder, MAP_DIRS), MAP_SUFFIXES + EVENT_SUFFIXES)
    scans, scan_twins = _by_stem(_first_dir(folder, LIDAR_DIRS), LIDAR_SUFFIXES)
    ambiguous = {stem: f"{' and '.join(str(p) for p in paths)} share the stem {stem!r}; keep one"
                 for stem, paths in {**map_twins, **scan_twins}.items()}
    pairs = {stem: (maps[stem], scans[stem]) for stem in sorted(maps.keys() & scans.keys()) if stem not in ambiguous}
    unpaired = [f"{maps[s]}: no lidar scan with stem {s!r}" for s in sorted(maps.keys() - scans.keys())]
    unpaired += [f"{scans[s]}: no event map with stem {s!r}" for s in sorted(scans.keys() - maps.keys())]
    return pairs, unpaired, {s: ambiguous[s] for s in sorted(ambiguous) if s in maps and s in scans}


def load_scene_folder(
    folder: str | Path,
    seed_file: str | Path | None = None,
    camera_file: str | Path | None = None,
    on_scene: Callable[[int, int, str], None] | None = None,
    use_cache: bool = True,
    map_kind: str | None = None,
) -> SceneSet:
    """Load every scene of ``folder``; ``map_kind`` ("events" or "image") overrides the kind
    found from each map's file and content.

    Raises :class:`InputError` when the folder, the camera or the seed cannot be used or when
    no scene loads; a single bad scene is recorded in ``failures`` instead.
    ``on_scene(i, n, name)`` is called before each scene is read (for progress bars).
    """
    root = Path(folder)
    if not root.is_dir():
        raise InputError(root, "scene folder does not exist" if not root.exists() else "not a folder")
    pairs, unpaired, ambiguous = find_scene_files(root)
    if not pairs and ambiguous:
        stem, problem = next(iter(ambiguous.items()))
        raise InputError(root, f"no unambiguous scene: {problem}")
    if not pairs:
        raise InputError(root, f"no scene found: expected {'|'.join(MAP_DIRS)}/<stem>.<map> paired with "
                               f"{'|'.join(LIDAR_DIRS)}/<stem>.<scan>")
    rig_path = Path(camera_file) if camera_file else _find_rig(root)
    rig = load_rig(rig_path)
    if seed_file is not None:
        seed, seed_source = load_seed(seed_file), str(seed_file)
    elif rig.seed is not None:
        seed, seed_source = rig.seed, str(rig_path)
    else:
        raise InputError(rig_path, "holds no seed extrinsic; pass one with --seed FILE")

    camera: CameraModel | None = rig.camera() if rig.width and rig.height else None
    scenes: list[Scene] = []
    failures = [SceneFailure(stem, problem) for stem, problem in ambiguous.items()]
    for i, (stem, (map_path, lidar_path)) in enumerate(pairs.items()):
        if on_scene:
            on_scene(i, len(pairs), stem)
        try:
            scene = load_scene(stem, map_path, lidar_path, camera, root if use_cache else None, map_kind)
            if camera is None:
                h, w = scene.event_map.shape
                camera = rig.camera(w, h)
            scenes.append(scene)
        except InputError as exc:
            failures.append(SceneFailure(stem, str(exc)))
    if not scenes:
        details = "; ".join(f.error for f in failures[:3])
        raise InputError(root, f"none of the {len(pairs)} scenes loaded ({details})")
    assert camera is not None
    notes = []
    photos = [s for s in scenes if s.map_kind == "image" and s.map_path is not None and guess_kind(s.map_path) == "events"]
    if photos and map_kind is None:
        notes.append(f"{len(photos)} map(s) under {photos[0].map_path.parent} look like camera images, not accumulated "
                     f"events (e.g. {photos[0].map_path.name}): scored as images; --map-kind events overrides")
    rescaled = [s for s in scenes if s.map_scale != 1.0]
    if rescaled:
        first = rescaled[0]
        notes.append(f"{len(rescaled)} map(s) had more than {MAX_CLIPPED_SHARE:.0%} of their non-zero pixels above the "
                     f"clip of {MAP_CLIP[first.map_kind]:g} (16-bit counts or a long window?), which would flatten them: "
                     f"rescaled so {RESCALED_CLIPPED_SHARE:.0%} lie above it (e.g. {first.map_path}: values x "
                     f"{first.map_scale:.4g})")
    return SceneSet(root, camera, seed, scenes, failures, unpaired, seed_source, str(rig_path), notes)


def load_scene(
    name: str,
    map_path: Path,
    lidar_path: Path,
    camera: CameraModel | None,
    cache_root: Path | None = None,
    map_kind: str | None = None,
) -> Scene:
    """Read one scene; checks the map size against ``camera`` when it is known. ``map_kind``
    ("events" or "image") overrides the kind found from the file and its content."""
    w, h = (camera.width, camera.height) if camera else (None, None)
    acc = Accumulation() if is_event_recording(map_path) else None
    settings = acc or Accumulation()
    event_map, kind = load_map(map_path, width=w, height=h, kind=map_kind, window_s=settings.window_s,
                               start_s=settings.start_s, hot_pixel_sigma=settings.hot_pixel_sigma)
    event_map, scale = fit_to_clip(event_map, kind)
    points, intensity = _load_scan_cached(lidar_path, cache_root)
    check_informative(map_path, event_map, lidar_path, intensity)
    return Scene(name, points, intensity, event_map, kind, lidar_path, map_path, acc, scale)


def reaccumulate(scene: Scene, settings: Accumulation, width: int, height: int) -> Scene:
    """``scene`` with its map accumulated again from its raw events per ``settings`` (cached like
    at load time); :class:`InputError` when the result cannot be used (e.g. an empty or constant
    window). A scene whose map is not a raw event recording is refused with ValueError."""
    if scene.accumulation is None or scene.map_path is None:
        raise ValueError(f"scene {scene.name}: its map is not a raw event recording")
    event_map = accumulate_with(scene.map_path, settings, width, height)
    check_informative(scene.map_path, event_map, scene.lidar_path or scene.map_path, scene.intensity)
    return replace(scene, event_map=np.ascontiguousarray(event_map, dtype=np.float32), accumulation=settings)


def check_informative(map_path: Path, event_map: np.ndarray, lidar_path: Path, intensity: np.ndarray) -> None:
    """Refuse a scene whose map or intensities are constant: its MI is zero wherever the lidar
    projects, so it cannot inform a calibration (and pooled with others it only dilutes them)."""
    lo, hi = float(np.min(event_map)), float(np.max(event_map))
    if lo == hi:
        raise InputError(map_path, f"the map is constant (every pixel is {lo:g}); it cannot inform a calibration")
    if intensity.size and float(np.min(intensity)) == float(np.max(intensity)):
        raise InputError(lidar_path, f"all {intensity.size} intensities are equal ({float(intensity[0]):g}); "
                                     "the MI needs varying lidar intensities")


# --- internals ------------------------------------------------------------------------------


def _first_dir(root: Path, names: tuple[str, ...]) -> Path | None:
    for name in names:
        if (root / name).is_dir():
            return root / name
    return None


def _by_stem(folder: Path | None, suffixes: tuple[str, ...]) -> tuple[dict[str, Path], dict[str, list[Path]]]:
    """``({stem: file}, {stem: [files]})``: the second holds stems that more than one file claims."""
    if folder is None:
        return {}, {}
    ordered = sorted(suffixes, key=len, reverse=True)  # ".pcd.bin" before ".bin"
    out: dict[str, Path] = {}
    twins: dict[str, list[Path]] = {}
    for path in sorted(folder.iterdir()):
        if not path.is_file() or path.name.startswith("."):
            continue
        lower = path.name.lower()
        for suffix in ordered:
            if lower.endswith(suffix) and len(lower) > len(suffix):
                stem = path.name[: -len(suffix)]
                if stem in out:
                    twins.setdefault(stem, [out[stem]]).append(path)
                out.setdefault(stem, path)
                break
    return out, twins


def _find_rig(root: Path) -> Path:
    for rel in RIG_FILES:
        if (root / rel).is_file():
            return root / rel
    raise InputError(root, f"no camera file: expected one of {', '.join(RIG_FILES)} (or pass --camera FILE)")


def _load_scan_cached(path: Path, cache_root: Path | None) -> tuple[np.ndarray, np.ndarray]:
    cache_file = None
    if cache_root is not None:
        st = path.stat()
        key = hashlib.sha1(os.fsencode(path.resolve()) + f"|{st.st_size}|{st.st_mtime_ns}|{SCAN_CACHE_VERSION}".encode()
                           ).hexdigest()[:16]
        cache_file = user_cache_dir("scans", folder_key(cache_root)) / f"{path.name}.{key}.npy"
        if cache_file.is_file():
            try:
                arr = np.load(cache_file)
                return np.ascontiguousarray(arr[:, :3]), np.ascontiguousarray(arr[:, 3])
            except (OSError, ValueError):
                pass  # a damaged cache entry is rebuilt below
    scan = load_lidar(path)
    if not scan.has_intensity:
        raise InputError(path, "has no intensity field (only x, y, z); the MI needs lidar intensities")
    if cache_file is not None:
        _write_cache(cache_file, np.column_stack([scan.points, scan.intensity]).astype(np.float32))
    return scan.points, scan.intensity


def _write_cache(cache_file: Path, arr: np.ndarray) -> None:
    """Best effort: a read-only scene folder simply goes uncached."""
    buf = io.BytesIO()
    np.save(buf, arr)
    try:
        if cache_file.parent.is_dir():  # entries of earlier versions of the scan
            for old in cache_file.parent.glob(cache_file.name.rsplit(".", 2)[0] + ".*.npy"):
                old.unlink(missing_ok=True)
        atomic_write_bytes(cache_file, buf.getvalue())
    except OSError:
        pass
