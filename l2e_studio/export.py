"""Result files: the calibration as YAML or JSON, written atomically, never overwritten silently.

A result file holds ``T_cam_lidar`` (4x4, maps lidar-frame points into the camera frame), its
inverse ``T_lidar_cam``, the same transform as translation / rotation vector / quaternion (xyzw) /
roll-pitch-yaw, the seed, the bounds and optimiser settings, the MI at the seed and at the result
(all scenes pooled and per scene), the evaluation count, the optimisation wall time and the scene
list. :func:`l2e_studio.io.cameras.load_seed` reads it back as a seed.
"""

from __future__ import annotations

import datetime as _dt
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import yaml

from . import __version__
from .atomic import atomic_write_bytes
from .calibrate import CalibrationResult
from .camera import CameraModel
from .geometry import Extrinsic
from .verdict import Verdict


def extrinsic_to_dict(ext: Extrinsic) -> dict:
    """Every representation of ``T_cam_lidar`` users ask for."""
    return {
        "T_cam_lidar": _round(ext.matrix),
        "T_lidar_cam": _round(ext.inverse().matrix),
        "translation": _round(ext.translation),
        "rotvec": _round(ext.rotvec),
        "quaternion_xyzw": _round(ext.quaternion_xyzw),
        "rpy_deg": _round(ext.rpy(degrees=True)),
    }


def result_to_dict(
    result: CalibrationResult,
    camera: CameraModel | None = None,
    scenes_dir: str | Path | None = None,
    quality: dict | None = None,
    verdict: Verdict | None = None,
) -> dict:
    """The result file's content as plain Python types (``quality``: an assessment, if run).

    With a ``verdict``, the calibration written at the top is the one the verdict hands back
    (the seed, when the result was not trusted); the optimiser's own answer stays on record
    under ``optimiser_result``."""
    ext = result.extrinsic if verdict is None else verdict.extrinsic
    s = result.settings
    out = {
        "l2e_studio_version": __version__,
        "created": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
        **extrinsic_to_dict(ext),
        "ros_static_transform": (
            "static_transform_publisher "
            + " ".join(f"{v:.6f}" for v in [*ext.translation, *ext.quaternion_xyzw])
            + " camera lidar"
        ),
        "seed": extrinsic_to_dict(result.seed),
        "bounds": {"translation_m": s.translation_bound, "rotation_deg": s.rotation_bound_deg},
        "optimiser": {
            "method": s.method,
            "sigma_px": s.sigma,
            "rotation_only": s.rotation_only,
            "max_iterations": s.max_iterations,
            "stages": [asdict(st) for st in result.stages],
            "message": result.message,
            "cancelled": result.cancelled,
        },
        "score": {
            "objective": result.objective,
            "seed": float(result.score_seed),
            "result": float(result.score_result),
            "per_scene": [
                {"scene": n, "seed": _f(a), "result": _f(b)}
                for n, a, b in zip(result.scene_names, result.score_seed_per_scene, result.score_result_per_scene)
            ],
        },
        "evaluations": int(result.evaluations),
        "optimisation_seconds": round(float(result.seconds), 4),
        "scenes": list(result.scene_names),
    }
    if verdict is not None:
        out["verdict"] = verdict.to_dict()
        out["optimiser_result"] = extrinsic_to_dict(result.extrinsic)
    if scenes_dir is not None:
        out["scenes_dir"] = str(scenes_dir)
    if quality is not None:
        out["quality"] = quality
    if camera is not None:
        out["camera"] = {
            "model": camera.model,
            "width": camera.width,
            "height": camera.height,
            "K": _round(camera.K),
            "D": _round(camera.D),
        }
    return out


def dumps(data: dict, path: str | Path) -> bytes:
    """Serialise as JSON when ``path`` ends in .json, YAML otherwise."""
    if str(path).lower().endswith(".json"):
        return (json.dumps(data, indent=2) + "\n").encode()
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120).encode()


def write_result(
    path: str | Path,
    result: CalibrationResult,
    camera: CameraModel | None = None,
    scenes_dir: str | Path | None = None,
    quality: dict | None = None,
    verdict: Verdict | None = None,
) -> tuple[Path, Path | None]:
    """Write the result file atomically. Returns ``(path, backup)``: an existing file at
    ``path`` is first kept under a timestamped backup name, never overwritten."""
    path = Path(path)
    return path, atomic_write_bytes(path, result_bytes(path, result, camera, scenes_dir, quality, verdict), keep_existing=True)


def result_bytes(
    path: str | Path,
    result: CalibrationResult,
    camera: CameraModel | None = None,
    scenes_dir: str | Path | None = None,
    quality: dict | None = None,
    verdict: Verdict | None = None,
) -> bytes:
    """The result file's bytes, in the format ``path``'s name asks for."""
    return dumps(result_to_dict(result, camera, scenes_dir, quality, verdict), path)


def _round(a) -> list:
    return np.round(np.asarray(a, dtype=np.float64), 10).tolist()


def _f(x: float) -> float | None:
    return None if not np.isfinite(x) else float(x)
