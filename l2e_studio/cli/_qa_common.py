"""Shared argument handling of the QA sub-commands (heldout, study, landscape, report)."""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from ..errors import InputError


def add_scene_args(p: argparse.ArgumentParser, bounds: bool = True) -> None:
    from .calibrate import DEFAULTS  # the CLI's copy of the engine defaults: no engine import for --help

    p.add_argument("--scenes", type=Path, help="scene folder (default: the embedded sample)")
    p.add_argument("--seed", type=Path, help="seed extrinsic file (overrides the folder's)")
    p.add_argument("--camera", type=Path, help="camera file (default: the folder's)")
    p.add_argument("--truth", type=Path, help="true extrinsic, when known (default: DIR/truth.yaml if present)")
    if bounds:
        p.add_argument("--bound-m", type=float, default=DEFAULTS["translation_bound"], help="translation bound, m (default: %(default)s)")
        p.add_argument("--bound-deg", type=float, default=DEFAULTS["rotation_bound_deg"], help="rotation bound, deg (default: %(default)s)")
        p.add_argument("--sigma", type=float, default=DEFAULTS["sigma"], help="map smoothing, px (default: %(default)s)")


def settings(args: argparse.Namespace, **kw) -> CalibrationSettings:
    from ..calibrate import CalibrationSettings

    try:
        return CalibrationSettings(translation_bound=args.bound_m, rotation_bound_deg=args.bound_deg, sigma=args.sigma, **kw)
    except ValueError as exc:
        raise InputError(None, str(exc)) from None


def check_files(args: argparse.Namespace) -> None:
    for name in ("seed", "camera", "truth"):
        path = getattr(args, name, None)
        if path is not None and not Path(path).is_file():
            raise InputError(path, f"{name} file does not exist")
    if getattr(args, "scenes", None) is not None and not Path(args.scenes).is_dir():
        raise InputError(args.scenes, "scene folder does not exist")


def load_scenes(args: argparse.Namespace):
    from ..samples import sample_scenes_dir
    from ..scenes import load_scene_folder

    check_files(args)
    ss = load_scene_folder(args.scenes or sample_scenes_dir(), args.seed, args.camera)
    for fail in ss.failures:
        print(f"warning: skipped scene {fail.name}: {fail.error}", file=sys.stderr)
    return ss


def truth(args: argparse.Namespace, root: Path) -> Extrinsic | None:
    from ..synth import read_truth

    path = args.truth or (Path(root) / "truth.yaml")
    return read_truth(path) if Path(path).is_file() else None


def check_writable(path: Path) -> None:
    """Fail early, before any work, when ``path`` cannot be written (its folder is read-only...)."""
    folder = Path(path).parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".l2e-probe-", dir=folder)
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise InputError(folder, f"cannot write here ({exc.strerror or exc})") from None


def write(path: Path, data: bytes) -> Path | None:
    """Atomic write (an existing file is kept as a backup); an unwritable place is one InputError."""
    from ..atomic import atomic_write_bytes

    try:
        return atomic_write_bytes(path, data, keep_existing=True)
    except OSError as exc:
        raise InputError(path, f"cannot write ({exc.strerror or exc})") from None


def dump(data: dict, path: Path) -> bytes:
    import yaml

    import json

    if str(path).lower().endswith(".json"):
        return (json.dumps(data, indent=2, default=str) + "\n").encode()
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=140).encode()


def read_doc(path: Path) -> dict:
    import yaml

    import json

    if not Path(path).is_file():
        raise InputError(path, "file not found")
    try:
        text = Path(path).read_text(encoding="utf-8")
        doc = json.loads(text) if str(path).lower().endswith(".json") else yaml.safe_load(text)
    except (ValueError, yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot parse ({str(exc).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        raise InputError(path, "expected a mapping")
    return doc
