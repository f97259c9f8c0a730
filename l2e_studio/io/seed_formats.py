"""Seeds from the export formats that are not YAML mappings: ROS 1 / ROS 2
``static_transform_publisher`` lines and URDF joints (see :func:`l2e_studio.export.export_text`).

``static_transform_publisher`` and a URDF joint give the pose of the child frame in the parent
frame, i.e. the transform that maps child-frame points into the parent frame. A seed is
``T_cam_lidar``, so the parent must be the camera and the child the lidar; when the parent's name
looks like the lidar's and the child's like a camera's, the transform is inverted.
"""

from __future__ import annotations

import re
import shlex
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import Extrinsic

_LIDAR_WORDS = ("lidar", "velodyne", "ouster", "livox", "hesai", "laser", "os_sensor", "rslidar", "pandar")


def seed_from_text(path: Path, text: str) -> Extrinsic | None:
    """The seed in ``text`` if it is a static_transform_publisher line or a URDF joint, else None."""
    if _STATIC_TF.search(text):
        return _static_tf(path, text)
    if re.search(r"^\s*<joint\b", text, re.MULTILINE):
        return _urdf(path, text)
    return None


#: a command line (not, say, a YAML field that quotes one)
_STATIC_TF = re.compile(r"^\s*(?:rosrun\s+\S+\s+|ros2\s+run\s+\S+\s+)?static_transform_publisher\b", re.MULTILINE)


def _oriented(ext: Extrinsic, parent: str, child: str) -> Extrinsic:
    lidar_parent = any(w in parent.lower() for w in _LIDAR_WORDS)
    lidar_child = any(w in child.lower() for w in _LIDAR_WORDS)
    return ext.inverse() if lidar_parent and not lidar_child else ext


def _static_tf(path: Path, text: str) -> Extrinsic:
    line = next(ln for ln in text.splitlines() if _STATIC_TF.match(ln))
    try:
        tokens = shlex.split(line.split("static_transform_publisher", 1)[1], comments=True)
    except ValueError as exc:
        raise InputError(path, f"cannot parse the static_transform_publisher line ({exc})") from None
    named: dict[str, str] = {}
    positional: list[str] = []
    i = 0
    while i < len(tokens):
        tok = tokens[i]
        if tok.startswith("--") and i + 1 < len(tokens):
            named[tok[2:].replace("_", "-")] = tokens[i + 1]
            i += 2
        else:
            positional.append(tok)
            i += 1
    try:
        if named:
            val = lambda k, d=0.0: float(named.get(k, d))  # noqa: E731
            t = [val("x"), val("y"), val("z")]
            parent, child = named.get("frame-id", ""), named.get("child-frame-id", "")
            if any(k in named for k in ("qx", "qy", "qz", "qw")):
                ext = Extrinsic.from_quaternion([val("qx"), val("qy"), val("qz"), val("qw", 1.0)], t)
            else:
                ext = Extrinsic.from_rpy([val("roll"), val("pitch"), val("yaw")], t, degrees=False)
            return _oriented(ext, parent, child)
        nums: list[float] = []
        for tok in positional:
            try:
                nums.append(float(tok))
            except ValueError:
                break
        frames = positional[len(nums):]
        if len(nums) == 7:  # x y z qx qy qz qw
            ext = Extrinsic.from_quaternion(nums[3:7], nums[:3])
        elif len(nums) == 6:  # x y z yaw pitch roll (radians)
            ext = Extrinsic.from_rpy([nums[5], nums[4], nums[3]], nums[:3], degrees=False)
        else:
            raise InputError(path, f"static_transform_publisher needs 6 or 7 numbers, found {len(nums)}")
        if len(frames) < 2:
            raise InputError(path, "static_transform_publisher line names no frame_id and child_frame_id")
        return _oriented(ext, frames[0], frames[1])
    except ValueError as exc:
        raise InputError(path, f"bad static_transform_publisher line ({exc})") from None


def _urdf(path: Path, text: str) -> Extrinsic:
    m = re.search(r"<joint\b.*?</joint>", text, re.DOTALL)
    if m is None:
        raise InputError(path, "URDF joint is not closed (</joint> missing)")
    try:
        joint = ET.fromstring(m.group(0))
    except ET.ParseError as exc:
        raise InputError(path, f"invalid URDF joint ({exc})") from None
    origin = joint.find("origin")
    parent = joint.find("parent")
    child = joint.find("child")
    try:
        xyz = np.array((origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split(), dtype=float)
        rpy = np.array((origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split(), dtype=float)
        ext = Extrinsic.from_rpy(rpy, xyz, degrees=False)
    except ValueError as exc:
        raise InputError(path, f"bad URDF origin ({exc})") from None
    return _oriented(ext, parent.get("link", "") if parent is not None else "", child.get("link", "") if child is not None else "")
