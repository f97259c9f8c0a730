"""Result files: the calibration as YAML or JSON, written atomically, never overwritten silently.

A result file holds ``T_cam_lidar`` (4x4, maps lidar-frame points into the camera frame), its
inverse ``T_lidar_cam``, the same transform as translation / rotation vector / quaternion (xyzw) /
roll-pitch-yaw, the seed, the bounds and optimiser settings, the MI at the seed and at the result
(all scenes pooled and per scene), the evaluation count, the optimisation wall time, the scene
list and, per scene, the map it was scored on (``maps``: file, kind, and the accumulation
window / start / hot-pixel sigma of maps built from raw events). :func:`l2e_studio.io.cameras.load_seed` reads it back as a seed.
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
    maps: dict[str, dict] | None = None,
    judging_cancelled: bool = False,
) -> dict:
    """The result file's content as plain Python types (``quality``: an assessment, if run;
    ``maps``: scene name -> how its map was made, see :meth:`l2e_studio.scenes.Scene.map_record`).

    With a ``verdict``, the calibration written at the top is the one the verdict hands back
    (the seed, when the result was not trusted); the optimiser's own answer stays on record
    under ``optimiser_result``. Without one, ``verdict:`` says ``not judged`` and why
    (``judging_cancelled``: the run finished but its judging was cancelled); ``cancelled`` at
    the top is true when the run or its judging was cancelled."""
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
            **({"edge_gradient": result.edge_gradient} if result.objective == "edges" else {}),
            "seed": float(result.score_seed),
            "result": float(result.score_result),
            "per_scene": [
                {"scene": n, "seed": _f(a), "result": _f(b)}
                for n, a, b in zip(result.scene_names, result.score_seed_per_scene, result.score_result_per_scene)
            ],
        },
        "method": result.method,
        "evaluations": int(result.evaluations),
        "optimisation_seconds": round(float(result.seconds), 4),
        "scenes": list(result.scene_names),
    }
    out["cancelled"] = bool(result.cancelled or judging_cancelled)
    if result.target is not None:  # the checkerboard method: its per-frame table and uncertainty
        out["optimiser"]["method"] = "least_squares"
        out["target"] = result.target.to_dict()
    if verdict is not None:
        out["verdict"] = verdict.to_dict()
        out["optimiser_result"] = extrinsic_to_dict(result.extrinsic)
    else:
        out["verdict"] = not_judged(result.cancelled, judging_cancelled)
    if maps is not None:
        out["maps"] = dict(maps)
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


NOT_JUDGED = "not judged"


def not_judged(run_cancelled: bool = False, judging_cancelled: bool = False) -> dict:
    """The ``verdict:`` section of a result that has no verdict, saying why."""
    why = ("the run was cancelled: its best point so far is not a converged result" if run_cancelled
           else "its judging was cancelled" if judging_cancelled
           else "the result was not judged (--no-verdict, or judging failed)")
    return {"status": NOT_JUDGED, "summary": f"{NOT_JUDGED}: {why}",
            "cancelled": bool(run_cancelled or judging_cancelled)}


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
    maps: dict[str, dict] | None = None,
    judging_cancelled: bool = False,
) -> tuple[Path, Path | None]:
    """Write the result file atomically. Returns ``(path, backup)``: an existing file at
    ``path`` is first kept under a timestamped backup name, never overwritten."""
    path = Path(path)
    data = result_bytes(path, result, camera, scenes_dir, quality, verdict, maps, judging_cancelled)
    return path, atomic_write_bytes(path, data, keep_existing=True)


def result_bytes(
    path: str | Path,
    result: CalibrationResult,
    camera: CameraModel | None = None,
    scenes_dir: str | Path | None = None,
    quality: dict | None = None,
    verdict: Verdict | None = None,
    maps: dict[str, dict] | None = None,
    judging_cancelled: bool = False,
) -> bytes:
    """The result file's bytes, in the format ``path``'s name asks for."""
    return dumps(result_to_dict(result, camera, scenes_dir, quality, verdict, maps, judging_cancelled), path)


def _round(a) -> list:
    return np.round(np.asarray(a, dtype=np.float64), 10).tolist()


def _f(x: float) -> float | None:
    return None if not np.isfinite(x) else float(x)


# --- exports of one extrinsic, each labelled with its direction ----------------------------------

#: ``--format`` names of :func:`export_text`, with the file name suffix each is written under.
EXPORT_FORMATS: dict[str, str] = {
    "yaml": ".yaml",
    "json": ".json",
    "matrix": ".txt",
    "ros1": ".ros1.txt",
    "ros2": ".ros2.txt",
    "urdf": ".urdf",
    "kalibr": ".kalibr.yaml",
}

DIRECTION = "T_cam_lidar: maps points from the lidar frame into the camera frame, X_cam = R X_lidar + t"


def export_status(result: dict | None) -> tuple[str, list[str]]:
    """``(status, lines)``: the verdict an export carries, in words. ``result``: the result
    file's content (None for a plain seed or transform file). ``status`` is the verdict's
    (``trusted``, ``trusted-rotation``, ``not-trusted``), ``not judged``, or ``no verdict`` for
    a file that is no calibration result; ``lines`` say what the transform is (for
    ``trusted-rotation``: that its translation is the seed's, not an estimate)."""
    if result is None:
        return "no verdict", ["status: no verdict (exported from a seed or transform file, not a calibration result)"]
    v = result.get("verdict")
    if not isinstance(v, dict):
        v = not_judged(bool(result.get("optimiser", {}).get("cancelled")))
    status = str(v.get("status") or ("trusted" if v.get("trusted") is True else
                                    "not-trusted" if v.get("trusted") is False else NOT_JUDGED))
    lines = [f"status: {status}" + (f" ({v['summary']})" if v.get("summary") else "")]
    if status == "trusted-rotation":
        from_seed = "".join(str(a) for a in v.get("translation_from_seed", "xyz"))
        if from_seed and set(from_seed) != set("xyz"):
            calibrated = ", ".join(a for a in "xyz" if a not in from_seed)
            lines.append(f"translation along {', '.join(from_seed)}: the SEED's, not calibrated (these scenes do not "
                         f"pin it down); along {calibrated}: calibrated; the rotation was calibrated and checked")
        else:
            lines.append("translation: the SEED's translation, not calibrated (these scenes do not pin it down); "
                         "only the rotation was calibrated and checked")
        lever = v.get("rotation_per_cm_of_seed_translation")
        if isinstance(lever, dict) and isinstance(lever.get("note"), str):
            lines.append(lever["note"])
    if status in ("trusted", "trusted-rotation") and isinstance(v.get("within_spread"), dict):
        lines.append("within the result's own spread the SEED's values stand: " + str(v["within_spread"].get("note", "")))
    if status == "not-trusted":
        lines.append("this is the SEED, not a calibration: the result was not trusted" if v.get("kept_seed", True)
                     else "this is the optimiser's result, which was NOT TRUSTED")
    elif status == NOT_JUDGED:
        lines.append("this transform was not checked" + (": the run or its judging was cancelled"
                                                        if v.get("cancelled") or result.get("cancelled") else ""))
    return status, lines


def export_text(
    ext: Extrinsic,
    fmt: str,
    camera_frame: str = "camera",
    lidar_frame: str = "lidar",
    result: dict | None = None,
) -> str:
    """``T_cam_lidar`` in one export format (see :data:`EXPORT_FORMATS`), with a comment (or a
    field) that says which frame maps to which, and the verdict (:func:`export_status`) as the
    format's comments (a ``status``/``status_notes`` field in JSON, which has none). Every one
    reads back through :func:`l2e_studio.io.cameras.load_seed`. ``result``: the full result dict
    (written whole for yaml/json; default: the transform alone, marked as no verdict)."""
    if fmt not in EXPORT_FORMATS:
        raise ValueError(f"unknown export format {fmt!r}; expected one of {', '.join(EXPORT_FORMATS)}")
    t, q = ext.translation, ext.quaternion_xyzw
    num = lambda v: f"{v:.9f}".rstrip("0").rstrip(".") if abs(v) > 0 else "0"  # noqa: E731
    status, notes = export_status(result)
    hashes = "".join(f"# {line}\n" for line in notes)
    if fmt in ("yaml", "json"):
        data = dict(result) if result is not None else {"direction": DIRECTION, **extrinsic_to_dict(ext)}
        data.setdefault("direction", DIRECTION)
        if fmt == "json":
            return json.dumps({"status": status, "status_notes": notes, **data}, indent=2) + "\n"
        return hashes + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120)
    if fmt == "matrix":
        rows = "\n".join(" ".join(f"{v: .10f}" for v in row) for row in ext.matrix)
        return f"# {DIRECTION}\n# frames: {lidar_frame} -> {camera_frame}; 4x4 homogeneous, row major\n{hashes}{rows}\n"
    if fmt == "ros1":
        args = " ".join(num(v) for v in [*t, *q])
        return (
            f"# ROS 1 (tf2_ros): publishes {camera_frame} -> {lidar_frame}, i.e. the pose of '{lidar_frame}' in "
            f"'{camera_frame}' = {DIRECTION}\n"
            f"# arguments: x y z qx qy qz qw frame_id child_frame_id\n{hashes}"
            f"rosrun tf2_ros static_transform_publisher {args} {camera_frame} {lidar_frame}\n"
        )
    if fmt == "ros2":
        named = " ".join(f"--{k} {num(v)}" for k, v in zip(("x", "y", "z", "qx", "qy", "qz", "qw"), [*t, *q]))
        return (
            f"# ROS 2 (tf2_ros): publishes {camera_frame} -> {lidar_frame}, i.e. the pose of '{lidar_frame}' in "
            f"'{camera_frame}' = {DIRECTION}\n{hashes}"
            f"ros2 run tf2_ros static_transform_publisher {named} --frame-id {camera_frame} --child-frame-id {lidar_frame}\n"
        )
    if fmt == "urdf":
        rpy = ext.rpy(degrees=False)
        # "--" may not appear inside an XML comment
        xml_notes = "".join(f"<!-- {line.replace('--', '- -')} -->\n" for line in notes)
        return (
            f"<!-- URDF fixed joint: parent '{camera_frame}', child '{lidar_frame}'; origin = pose of the child in the "
            f"parent = T_cam_lidar (maps lidar-frame points into the camera frame). rpy in radians, "
            f"R = Rz(yaw) Ry(pitch) Rx(roll) -->\n{xml_notes}"
            f'<joint name="{camera_frame}_to_{lidar_frame}" type="fixed">\n'
            f'  <parent link="{camera_frame}"/>\n'
            f'  <child link="{lidar_frame}"/>\n'
            f'  <origin xyz="{" ".join(num(v) for v in t)}" rpy="{" ".join(num(v) for v in rpy)}"/>\n'
            f"</joint>\n"
        )
    # kalibr
    data = {"cam0": {"T_cam_lidar": _round(ext.matrix), "rostopic": f"/{camera_frame}"}}
    return (
        f"# Kalibr-style camchain entry. {DIRECTION} (4x4, row major), as Kalibr's T_cam_imu is imu -> cam\n{hashes}"
        + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=200)
    )


def write_export(path: str | Path, ext: Extrinsic, fmt: str, **kwargs) -> Path:
    """Write one export atomically (an existing file is kept as a timestamped backup)."""
    text = export_text(ext, fmt, **kwargs)
    path = Path(path)
    atomic_write_bytes(path, text.encode(), keep_existing=True)
    return path
