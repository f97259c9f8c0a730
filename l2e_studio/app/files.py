"""Files the workbench writes: result + before/after PNG, and seed files.

Names carry a timestamp and never replace an existing file (a clash gets ``-1``, ``-2``...);
the writing itself is :mod:`l2e_studio.export`'s (atomic, the headless command's format).
"""

from __future__ import annotations

import datetime as _dt
import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np
import yaml

from ..calibrate import CalibrationResult
from ..camera import CameraModel
from ..errors import InputError
from ..atomic import atomic_write_bytes
from ..export import dumps, extrinsic_to_dict, result_to_dict, write_result
from ..geometry import Extrinsic
from ..verdict import Verdict
from ..io.cameras import load_seed
from .heldout import HeldOutScore, held_out_section
from ..io.safe_load import MAX_DOCUMENT_BYTES
from .overlay import encode_png

SEED_SUFFIXES = (".yaml", ".yml", ".json", ".txt", ".npy")


def default_results_dir(scenes_root: str | Path, cwd: Path | None = None) -> Path:
    """``./l2e_results/<scene folder name>``: beside where the app runs, never inside the data."""
    return (cwd or Path.cwd()) / "l2e_results" / Path(scenes_root).resolve().name


def check_results_dir(text: str, scenes_root: str | Path) -> tuple[Path | None, str]:
    """(folder, note) for a results folder typed by hand; folder None when it cannot be one."""
    text = str(text).strip()
    if not text:
        return None, "the results folder cannot be empty"
    folder = Path(text).expanduser()
    if not folder.is_absolute():
        folder = Path.cwd() / folder
    if folder.exists() and not folder.is_dir():
        return None, f"{folder} is a file, not a folder"
    root = Path(scenes_root).resolve()
    try:
        folder.resolve().relative_to(root)
        return folder, f"{folder} is inside the scene folder: results will be written into the data"
    except ValueError:
        return folder, ""


def fresh_path(folder: Path, stem: str, suffix: str, when: _dt.datetime | None = None) -> Path:
    """``folder/<stem>_<YYYYmmdd-HHMMSS>[-n]<suffix>`` that does not exist yet."""
    stamp = (when or _dt.datetime.now()).strftime("%Y%m%d-%H%M%S")
    for i in range(1000):
        path = folder / f"{stem}_{stamp}{'-' + str(i) if i else ''}{suffix}"
        if not path.exists() and not path.with_name(path.stem + "_before_after.png").exists():
            return path
    raise FileExistsError(f"no free file name for {stem} in {folder}")


def save_result(
    folder: Path, result: CalibrationResult, camera: CameraModel, scenes_dir: Path, before_after: np.ndarray | None,
    held_out: Sequence[HeldOutScore] = (),
    verdict: Verdict | None = None,
    maps: dict[str, dict] | None = None,
    judging_cancelled: bool = False,
) -> tuple[Path, Path | None]:
    """Write the result file (YAML, with the ``verdict``, or ``not judged`` and why, and
    ``maps``: how each scene's map was made) and, when given, the before/after image beside it.

    Held-out scenes (scored, not optimised over) are listed in ``mi.per_scene`` with
    ``held_out: true`` and by name in ``scenes_held_out``; ``scenes`` stays the optimised ones.
    """
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(folder, f"cannot create the results folder ({exc.strerror})") from None
    path = fresh_path(folder, "l2e_result", ".yaml")
    if held_out:
        doc = result_to_dict(result, camera, scenes_dir, verdict=verdict, maps=maps, judging_cancelled=judging_cancelled)
        doc["score"]["per_scene"] += held_out_section(held_out)
        doc["scenes_held_out"] = [r.name for r in held_out]
        atomic_write_bytes(path, dumps(doc, path), keep_existing=True)
    else:
        write_result(path, result, camera, scenes_dir, verdict=verdict, maps=maps, judging_cancelled=judging_cancelled)
    png = None
    if before_after is not None:
        png = path.with_name(path.stem + "_before_after.png")
        atomic_write_bytes(png, encode_png(before_after))
    return path, png


def seed_document(extrinsic: Extrinsic, note: str = "", pairs: Sequence = ()) -> bytes:
    """A seed file (``seed:`` section of our camera.yaml) that :func:`load_seed` reads back;
    clicked ``pairs`` (lidar point, map pixel) go along under ``pairs``."""
    rep = extrinsic_to_dict(extrinsic)
    doc = {"seed": {"translation": rep["translation"], "rotvec": rep["rotvec"]},
           "as_matrix": {"T_cam_lidar": rep["T_cam_lidar"]}, "rpy_deg": rep["rpy_deg"]}
    if pairs:
        doc["pairs"] = [{"lidar_m": [float(a) for a in p.point], "pixel": [float(a) for a in p.pixel]} for p in pairs]
    header = "# Seed T_cam_lidar (X_cam = R X_lidar + t), written by the L2E Studio workbench.\n"
    if note:
        header += f"# {note}\n"
    return (header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)).encode()


def save_seed(folder: Path, extrinsic: Extrinsic, pairs: Sequence = ()) -> Path:
    path = fresh_path(Path(folder), "seed", ".yaml")
    atomic_write_bytes(path, seed_document(extrinsic, pairs=pairs))
    return path


def seed_from_upload(name: str, content: bytes) -> Extrinsic:
    """Parse an uploaded seed file (any format :func:`load_seed` knows) without keeping it."""
    suffix = Path(name).suffix.lower()
    if suffix not in SEED_SUFFIXES:
        raise InputError(name, f"unsupported seed file type {suffix or '(none)'}; expected one of {', '.join(SEED_SUFFIXES)}")
    if len(content) > MAX_DOCUMENT_BYTES:  # refused before it is written anywhere or parsed
        raise InputError(name, f"is {len(content) / 2**20:.1f} MiB; a seed file is at most {MAX_DOCUMENT_BYTES // 2**20} MiB")
    with tempfile.TemporaryDirectory(prefix="l2e_seed_") as tmp:
        path = Path(tmp) / Path(name).name
        path.write_bytes(content)
        try:
            return load_seed(path)
        except InputError as exc:
            raise InputError(name, exc.problem) from None
