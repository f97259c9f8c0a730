"""Camera intrinsics (and a seed extrinsic, where the file has one) from the formats rigs use.

:func:`load_rig` auto-detects the format from the file's content:

* ``camera.yaml`` (ours): ``camera: {model, width, height, K, D}`` + optional
  ``seed: {translation, rotvec | rpy_deg | quaternion_xyzw | matrix}``;
* the reference code's ``config.json``: ``{"cam": {"K", "D", "x", "y", "z", "Rodrigues", "rx", "ry", "rz"}}``
  (seed from x, y, z + the Rodrigues rotation vector, or rx, ry, rz in degrees as roll, pitch,
  yaw when Rodrigues is absent; no image size: it comes from the maps);
* OpenCV ``FileStorage`` YAML/XML (``camera_matrix`` / ``distortion_coefficients`` as
  ``!!opencv-matrix``, optional ``image_width``/``image_height``, ``distortion_model``);
* Kalibr camchain YAML (``cam0: {camera_model: pinhole, intrinsics: [fu, fv, pu, pv],
  distortion_model: radtan | equidistant, distortion_coeffs, resolution: [w, h]}``; the first
  camera, or the one named by ``camera=``; a ``T_cam_lidar`` entry, if present, is the seed);
* ROS ``camera_info`` YAML (``image_width``, ``camera_matrix: {rows, cols, data}``,
  ``distortion_model: plumb_bob | rational_polynomial | equidistant``, ``distortion_coefficients``);
* OpenCalib (SensorsCalibration) ``*-intrinsic.json`` (``param.cam_K``, ``param.cam_dist``) and
  ``calib.txt`` (``K:``, ``D:``, ``T:`` lines, T = lidar -> camera 3x4);
* KITTI ``calib.txt`` (odometry and object: ``P0:``..``P3:``, ``Tr:`` or ``R0_rect:`` +
  ``Tr_velo_to_cam:``): the rectified camera ``P2`` (or the one named by ``camera=``), no
  distortion, no image size (it comes from the maps); the seed lidar -> that camera.

:func:`load_seed` reads a seed ``T_cam_lidar`` from any of those, from a result file written
by :mod:`l2e_studio.export` (``T_cam_lidar`` 4x4), an OpenCalib extrinsic json
(``sensor_calib``), a plain 4x4 matrix (``.txt``, ``.npy``, ``.json`` list) or a YAML/JSON
mapping with ``translation`` + ``rotvec`` / ``quaternion_xyzw`` / ``rpy_deg`` / ``matrix``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..camera import CameraModel
from ..errors import InputError
from ..geometry import Extrinsic
from ..limits import MAX_IMAGE_SIDE, ROTATION_TOLERANCE
from .safe_load import MAX_DOCUMENT_BYTES, load_npy, parse_json, parse_yaml, read_text_capped

#: ROS / OpenCV / Kalibr distortion model names -> ours.
MODEL_NAMES = {
    "radtan": "radtan", "plumb_bob": "radtan", "rational_polynomial": "radtan", "pinhole": "radtan",
    "brown": "radtan", "opencv": "radtan", "radial-tangential": "radtan",
    "equidistant": "equidistant", "equi": "equidistant", "fisheye": "equidistant", "kannala_brandt": "equidistant",
}


@dataclass
class RigFile:
    """Intrinsics (and maybe a seed) as read from one file; the image size may be unknown."""

    K: np.ndarray
    D: np.ndarray
    model: str
    width: int | None
    height: int | None
    seed: Extrinsic | None
    source: Path
    format: str

    def camera(self, width: int | None = None, height: int | None = None) -> CameraModel:
        """The :class:`CameraModel`; ``width``/``height`` (e.g. from the maps) win over the file's."""
        w = width if width is not None else self.width
        h = height if height is not None else self.height
        if w is None or h is None:
            raise InputError(self.source, "the image size is not in this file; it must come from the maps")
        w, h = int(w), int(h)
        if not (0 < w <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE):
            raise InputError(self.source, f"image size {w}x{h} is outside 1..{MAX_IMAGE_SIDE} pixels per side")
        cx, cy = self.K[0, 2], self.K[1, 2]
        if not (0 <= cx <= w and 0 <= cy <= h):
            raise InputError(self.source, f"the principal point ({cx:g}, {cy:g}) lies outside the {w}x{h} image")
        try:
            return CameraModel(self.K, w, h, self.D, self.model)
        except ValueError as exc:
            raise InputError(self.source, str(exc)) from exc


def load_rig(path: str | Path, camera: str | None = None) -> RigFile:
    """Read intrinsics (+ seed where present) from any supported file, auto-detecting the format."""
    path = Path(path)
    doc = _read_document(path)
    if isinstance(doc, str):  # a text format
        if KITTI_TEXT.search(doc):
            return _kitti_txt(path, doc, camera)
        if re.search(r"^\s*K\s*:", doc, re.MULTILINE):
            return _opencalib_txt(path, doc)
        raise InputError(path, "unknown camera file format (not YAML/JSON with camera intrinsics)")
    if not isinstance(doc, dict):
        raise InputError(path, f"expected a mapping of camera parameters, got {type(doc).__name__}")
    for detect, reader in _READERS:
        if detect(doc):
            return reader(path, doc, camera) if reader is _kalibr else reader(path, doc)
    keys = ", ".join(list(doc)[:8])
    raise InputError(path, f"unknown camera file format (top-level keys: {keys})")


def load_seed(path: str | Path) -> Extrinsic:
    """Read a seed ``T_cam_lidar`` from any supported file (see the module docstring)."""
    path = Path(path)
    if path.suffix.lower() == ".npy":
        if not path.is_file():
            raise InputError(path, "seed file not found")
        if path.stat().st_size > MAX_DOCUMENT_BYTES:
            raise InputError(path, f"a seed matrix file is at most {MAX_DOCUMENT_BYTES // 2**20} MiB")
        try:
            return _extrinsic_from_matrix(path, load_npy(path))
        except InputError:
            raise
        except (ValueError, OSError) as exc:
            raise InputError(path, f"cannot read the .npy matrix ({exc})") from exc
    if path.is_file() and path.stat().st_size < 1_000_000:
        from .seed_formats import seed_from_text  # ROS static_transform_publisher lines, URDF joints

        try:
            special = seed_from_text(path, path.read_text(encoding="utf-8"))
        except UnicodeDecodeError:
            special = None
        if special is not None:
            return special
    doc = _read_document(path)
    if isinstance(doc, str):
        if KITTI_TEXT.search(doc):
            seed = _kitti_txt(path, doc).seed
            if seed is None:
                raise InputError(path, "a KITTI calib.txt without a 'Tr:' or 'Tr_velo_to_cam:' line has no seed")
            return seed
        if re.search(r"^\s*T\s*:", doc, re.MULTILINE):
            seed = _opencalib_txt(path, doc).seed
            assert seed is not None
            return seed
        body = "\n".join(line.split("#", 1)[0] for line in doc.splitlines())
        try:
            values = np.array(body.replace(",", " ").replace("[", " ").replace("]", " ").split(), dtype=np.float64)
        except ValueError:
            raise InputError(path, "not a 4x4 matrix nor a known seed format") from None
        if values.size not in (12, 16):
            raise InputError(path, f"a matrix file must hold 12 or 16 numbers, found {values.size}")
        return _extrinsic_from_matrix(path, values.reshape(-1, 4))
    if isinstance(doc, list):
        return _extrinsic_from_matrix(path, doc)
    if isinstance(doc, dict):
        seed = _seed_anywhere(path, doc)
        if seed is not None:
            return seed
        try:
            rig = load_rig(path)
        except InputError:
            rig = None
        if rig is not None and rig.seed is not None:
            return rig.seed
        raise InputError(path, "no seed extrinsic found (expected T_cam_lidar, seed, translation + rotvec, ...)")
    raise InputError(path, f"cannot read a seed from a {type(doc).__name__}")


# --- reading ------------------------------------------------------------------------------

def _read_document(path: Path) -> Any:
    """Parse JSON / YAML / OpenCV FileStorage; return the raw text when it is none of those."""
    text = read_text_capped(path)
    if not text.strip():
        raise InputError(path, "the file is empty")
    if text.lstrip().startswith("%YAML") or "opencv-matrix" in text or text.lstrip().startswith("<?xml"):
        return _read_opencv_storage(path)
    if path.suffix.lower() == ".json":
        return parse_json(path, text)
    try:
        doc = parse_yaml(path, text)
    except yaml.YAMLError as exc:
        if re.search(r"^\s*K\s*:", text, re.MULTILINE):
            return text
        raise InputError(path, f"invalid YAML ({str(exc).splitlines()[0]})") from None
    if isinstance(doc, (str, int, float)) or doc is None:
        return text
    if isinstance(doc, dict) and any(isinstance(doc.get(k), str) for k in ("K", *KITTI_CAMERAS)):
        return text  # OpenCalib's and KITTI's calib.txt happen to parse as YAML with string values
    return doc


def _read_opencv_storage(path: Path) -> dict:
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # the binding reports a parse error as SystemError
        cause = exc.__cause__ or exc
        raise InputError(path, f"malformed OpenCV FileStorage ({str(cause).strip().splitlines()[-1]})") from None
    try:
        if not fs.isOpened():
            raise InputError(path, "cannot open as an OpenCV FileStorage YAML/XML file")
        root = fs.root()
        out: dict[str, Any] = {"__opencv__": True}
        for key in root.keys():
            node = fs.getNode(key)
            if node.isMap() and node.getNode("data").isSeq():
                out[key] = node.mat()
            elif node.isReal() or node.isInt():
                out[key] = node.real()
            elif node.isString():
                out[key] = node.string()
            elif node.isSeq():
                out[key] = [node.at(i).real() for i in range(node.size())]
            else:
                out[key] = node.mat()
        return out
    except cv2.error as exc:
        raise InputError(path, f"malformed OpenCV FileStorage ({str(exc).strip().splitlines()[-1]})") from None
    finally:
        fs.release()


# --- numeric helpers ---------------------------------------------------------------------

def _matrix(path: Path, value: Any, shape: tuple[int, int], what: str) -> np.ndarray:
    if isinstance(value, dict) and "data" in value:
        value = value["data"]
    try:
        arr = np.array(value, dtype=np.float64)
    except (ValueError, TypeError):
        raise InputError(path, f"{what} is not numeric") from None
    if arr.size == shape[0] * shape[1]:
        arr = arr.reshape(shape)
    if arr.shape != shape:
        raise InputError(path, f"{what} must be {shape[0]}x{shape[1]}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(path, f"{what} has NaN or infinite entries")
    return arr


def _vector(path: Path, value: Any, what: str, sizes: tuple[int, ...] | None = None) -> np.ndarray:
    if isinstance(value, dict) and "data" in value:
        value = value["data"]
    try:
        arr = np.array(value if value is not None else [], dtype=np.float64).ravel()
    except (ValueError, TypeError):
        raise InputError(path, f"{what} is not numeric") from None
    if not np.all(np.isfinite(arr)):
        raise InputError(path, f"{what} has NaN or infinite entries")
    if sizes is not None and arr.size not in sizes:
        raise InputError(path, f"{what} must have {' or '.join(map(str, sizes))} values, got {arr.size}")
    return arr


def _check_K(path: Path, K: np.ndarray) -> np.ndarray:
    """A physical pinhole K: positive focal lengths of one order, ``[0, 0, 1]`` last row, no shear below."""
    fx, fy = K[0, 0], K[1, 1]
    if fx <= 0 or fy <= 0:
        raise InputError(path, f"K has non-positive focal lengths fx={fx}, fy={fy}")
    if not np.allclose(K[2], [0, 0, 1], atol=1e-9) or abs(K[1, 0]) > 1e-9:
        raise InputError(path, f"K is not a pinhole matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]] "
                               f"(rows 2-3 are {K[1].tolist()}, {K[2].tolist()})")
    if max(fx, fy) / min(fx, fy) > 10 or abs(K[0, 1]) > 0.1 * fx:
        raise InputError(path, f"K is not physical: fx={fx:g}, fy={fy:g}, skew={K[0, 1]:g}")
    if not (0 < max(fx, fy) < 1e6):
        raise InputError(path, f"K has an absurd focal length ({max(fx, fy):g} px)")
    return K


def _distortion(path: Path, D: np.ndarray, model: str) -> np.ndarray:
    if model == "equidistant":
        if D.size == 0:
            return np.zeros(4)
        if D.size != 4:
            raise InputError(path, f"equidistant distortion takes 4 coefficients (k1..k4), got {D.size}")
        return D
    if D.size == 0:
        return np.zeros(5)
    if D.size in (4, 5, 8):
        return D
    if D.size in (12, 14) and np.allclose(D[8:], 0):  # OpenCV's full vector with unused thin-prism/tilt terms
        return D[:8]
    raise InputError(path, f"radtan distortion takes 4, 5 or 8 coefficients, got {D.size}")


def _model(path: Path, name: Any) -> str:
    key = str(name or "radtan").strip().lower()
    if key not in MODEL_NAMES:
        raise InputError(path, f"unknown distortion model {name!r}; expected radtan/plumb_bob or equidistant/fisheye")
    return MODEL_NAMES[key]


def _size(path: Path, value: Any, what: str) -> int | None:
    """An image side in pixels, or None when absent; anything else non-numeric or absurd is an error."""
    if value is None:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(path, f"{what} must be a number of pixels, got {value!r}") from None
    if v == 0:  # camera_info's "unknown"
        return None
    if not np.isfinite(v) or v != round(v) or not 0 < v <= MAX_IMAGE_SIDE:
        raise InputError(path, f"{what} must be a whole number of pixels in 1..{MAX_IMAGE_SIDE}, got {value!r}")
    return int(v)


def _extrinsic_from_matrix(path: Path, value: Any) -> Extrinsic:
    """A 4x4 or 3x4 ``T_cam_lidar``; the rotation block must be a rotation within tolerance
    (a sheared or scaled matrix is refused, not silently orthonormalised)."""
    if isinstance(value, dict):
        value = value.get("data")
    try:
        T = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(path, "the transform matrix is not numeric or its rows differ in length") from None
    if T.size == 16:
        T = T.reshape(4, 4)
    elif T.size == 12:
        T = T.reshape(3, 4)
    else:
        raise InputError(path, f"a transform must be 4x4 or 3x4, got {T.size} values")
    if not np.all(np.isfinite(T)):
        raise InputError(path, "the transform matrix has NaN or infinite entries")
    if T.shape == (4, 4) and not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6):
        raise InputError(path, f"the last row of a 4x4 transform must be [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    with np.errstate(over="ignore", invalid="ignore"):  # entries like 1e200: inf, refused just below
        off = float(np.abs(R.T @ R - np.eye(3)).max())
        det = float(np.linalg.det(R))
    if off > ROTATION_TOLERANCE or abs(det - 1) > ROTATION_TOLERANCE:
        raise InputError(path, f"the rotation block is not a rotation (max |R^T R - I| = {off:.2g}, "
                               f"determinant {det:.4g}; tolerance {ROTATION_TOLERANCE:g})")
    if np.abs(T[:3, 3]).max() > 1000:
        raise InputError(path, f"the translation {T[:3, 3].tolist()} is over a kilometre; expected metres")
    try:
        return Extrinsic.from_matrix(T)
    except ValueError as exc:
        raise InputError(path, f"bad transform matrix ({exc})") from None


def _seed_from_mapping(path: Path, d: dict) -> Extrinsic | None:
    """A seed from a mapping holding a matrix or translation + a rotation in some form."""
    for key in ("T_cam_lidar", "matrix", "T", "transform"):
        if key in d and d[key] is not None and not isinstance(d[key], str):
            return _extrinsic_from_matrix(path, d[key])
    if "translation" not in d:
        return None
    t = _vector(path, d["translation"], "seed translation", (3,))
    try:
        if "rotvec" in d:
            return Extrinsic(_vector(path, d["rotvec"], "seed rotvec", (3,)), t)
        if "quaternion_xyzw" in d:
            q = _vector(path, d["quaternion_xyzw"], "seed quaternion", (4,))
            if abs(float(np.linalg.norm(q)) - 1) > ROTATION_TOLERANCE:
                raise InputError(path, f"seed quaternion_xyzw has norm {np.linalg.norm(q):.4g}; a rotation is a unit "
                                       f"quaternion (tolerance {ROTATION_TOLERANCE:g})")
            return Extrinsic.from_quaternion(q, t)
        if "rpy_deg" in d:
            return Extrinsic.from_rpy(_vector(path, d["rpy_deg"], "seed rpy_deg", (3,)), t)
        if "rotation_matrix" in d:
            R = _matrix(path, d["rotation_matrix"], (3, 3), "seed rotation_matrix")
            return _extrinsic_from_matrix(path, np.column_stack([R, t]))
    except InputError:
        raise
    except ValueError as exc:
        raise InputError(path, f"bad seed ({exc})") from None
    raise InputError(path, "seed has a translation but no rotvec, quaternion_xyzw, rpy_deg or matrix")


def _seed_anywhere(path: Path, doc: dict) -> Extrinsic | None:
    """Look for a seed at the top level, then under the usual section names."""
    seed = _seed_from_mapping(path, doc)
    if seed is not None:
        return seed
    for key in ("seed", "extrinsic", "result", "calibration"):
        if isinstance(doc.get(key), dict):
            seed = _seed_from_mapping(path, doc[key])
            if seed is not None:
                return seed
    for value in doc.values():  # Kalibr-style camchain: {cam0: {T_cam_lidar: 4x4, ...}}
        if isinstance(value, dict) and isinstance(value.get("T_cam_lidar"), list):
            return _extrinsic_from_matrix(path, value["T_cam_lidar"])
    for value in doc.values():  # OpenCalib extrinsic json: {name: {param: {sensor_calib: {data}}}}
        if isinstance(value, dict) and isinstance(value.get("param"), dict) and "sensor_calib" in value["param"]:
            return _extrinsic_from_matrix(path, value["param"]["sensor_calib"])
    if "cam" in doc and isinstance(doc["cam"], dict):
        return _reference_seed(path, doc["cam"])
    return None


# --- the formats ---------------------------------------------------------------------------

def _is_ours(doc: dict) -> bool:
    return isinstance(doc.get("camera"), dict) and "K" in doc["camera"]


def _ours(path: Path, doc: dict) -> RigFile:
    cam = doc["camera"]
    model = _model(path, cam.get("model", "radtan"))
    K = _check_K(path, _matrix(path, cam["K"], (3, 3), "camera.K"))
    D = _distortion(path, _vector(path, cam.get("D"), "camera.D"), model)
    seed = _seed_from_mapping(path, doc["seed"]) if isinstance(doc.get("seed"), dict) else None
    return RigFile(K, D, model, _size(path, cam.get("width"), "width"), _size(path, cam.get("height"), "height"), seed, path, "camera.yaml")


def _is_reference(doc: dict) -> bool:
    return isinstance(doc.get("cam"), dict)


def _reference_seed(path: Path, cam: dict) -> Extrinsic | None:
    if not all(k in cam for k in ("x", "y", "z")):
        return None
    t = _vector(path, [cam["x"], cam["y"], cam["z"]], "cam x, y, z", (3,))
    if "Rodrigues" in cam:
        return Extrinsic(_vector(path, cam["Rodrigues"], "cam.Rodrigues", (3,)), t)
    if all(k in cam for k in ("rx", "ry", "rz")):
        return Extrinsic.from_rpy(_vector(path, [cam["rx"], cam["ry"], cam["rz"]], "cam rx, ry, rz", (3,)), t)
    return None


def _reference(path: Path, doc: dict) -> RigFile:
    cam = doc["cam"]
    if "K" not in cam:
        raise InputError(path, "config has no cam.K (3x3 intrinsic matrix)")
    K = _check_K(path, _matrix(path, cam["K"], (3, 3), "cam.K"))
    D = _distortion(path, _vector(path, cam.get("D"), "cam.D"), "radtan")
    return RigFile(K, D, "radtan", _size(path, cam.get("width"), "width"), _size(path, cam.get("height"), "height"),
                   _reference_seed(path, cam), path, "reference config.json")


def _is_opencv(doc: dict) -> bool:
    return any(k in doc for k in ("camera_matrix", "cameraMatrix", "K", "M1")) and not _is_ros(doc)


def _opencv(path: Path, doc: dict) -> RigFile:
    key = next(k for k in ("camera_matrix", "cameraMatrix", "K", "M1") if k in doc)
    K = _check_K(path, _matrix(path, doc[key], (3, 3), key))
    dkey = next((k for k in ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "D1") if k in doc), None)
    model = _model(path, doc.get("distortion_model", "fisheye" if doc.get("fisheye") else "radtan"))
    D = _distortion(path, _vector(path, doc[dkey] if dkey else None, dkey or "D"), model)
    seed = _seed_from_mapping(path, doc) if "T_cam_lidar" in doc else None
    return RigFile(K, D, model, _size(path, doc.get("image_width", doc.get("width")), "image_width"),
                   _size(path, doc.get("image_height", doc.get("height")), "image_height"), seed, path, "OpenCV YAML")


def _is_ros(doc: dict) -> bool:
    return isinstance(doc.get("camera_matrix"), dict) and "data" in doc["camera_matrix"] and "image_width" in doc


def _ros(path: Path, doc: dict) -> RigFile:
    K = _check_K(path, _matrix(path, doc["camera_matrix"], (3, 3), "camera_matrix"))
    model = _model(path, doc.get("distortion_model", "plumb_bob"))
    D = _distortion(path, _vector(path, doc.get("distortion_coefficients"), "distortion_coefficients"), model)
    return RigFile(K, D, model, _size(path, doc.get("image_width"), "image_width"), _size(path, doc.get("image_height"), "image_height"), None, path,
                   "ROS camera_info YAML")


def _kalibr_cameras(doc: dict) -> list[str]:
    return [k for k, v in doc.items() if isinstance(v, dict) and "intrinsics" in v]


def _is_kalibr(doc: dict) -> bool:
    return bool(_kalibr_cameras(doc))


def _kalibr(path: Path, doc: dict, camera: str | None = None) -> RigFile:
    names = _kalibr_cameras(doc)
    name = camera or names[0]
    if name not in names:
        raise InputError(path, f"no camera {name!r} in the camchain; cameras are {', '.join(names)}")
    cam = doc[name]
    if str(cam.get("camera_model", "pinhole")).lower() != "pinhole":
        raise InputError(path, f"{name}: camera_model {cam.get('camera_model')!r} is not supported (only pinhole)")
    fu, fv, pu, pv = _vector(path, cam["intrinsics"], f"{name}.intrinsics", (4,))
    K = _check_K(path, np.array([[fu, 0, pu], [0, fv, pv], [0, 0, 1]], dtype=np.float64))
    model = _model(path, cam.get("distortion_model", "radtan"))
    D = _vector(path, cam.get("distortion_coeffs"), f"{name}.distortion_coeffs")
    if model == "radtan" and D.size == 4:
        D = np.append(D, 0.0)
    D = _distortion(path, D, model)
    res = cam.get("resolution") or [None, None]
    if not isinstance(res, (list, tuple)) or len(res) != 2:
        raise InputError(path, f"{name}.resolution must be [width, height], got {res!r}")
    seed = _extrinsic_from_matrix(path, cam["T_cam_lidar"]) if "T_cam_lidar" in cam else None
    return RigFile(K, D, model, _size(path, res[0], f"{name}.resolution width"), _size(path, res[1], f"{name}.resolution height"), seed, path, "Kalibr camchain YAML")


def _opencalib_param(doc: dict) -> dict | None:
    """The ``param`` section of an OpenCalib intrinsic json (``{name: {param: {cam_K ...}}}``)."""
    return next((v["param"] for v in doc.values()
                 if isinstance(v, dict) and isinstance(v.get("param"), dict) and "cam_K" in v["param"]), None)


def _is_opencalib_intrinsic(doc: dict) -> bool:
    return _opencalib_param(doc) is not None


def _opencalib_intrinsic(path: Path, doc: dict) -> RigFile:
    param = _opencalib_param(doc)
    K = _check_K(path, _matrix(path, param["cam_K"], (3, 3), "cam_K"))
    D = _distortion(path, _vector(path, param.get("cam_dist"), "cam_dist"), "radtan")
    return RigFile(K, D, "radtan", _size(path, param.get("img_dist_w"), "img_dist_w"), _size(path, param.get("img_dist_h"), "img_dist_h"), None, path,
                   "OpenCalib intrinsic json")


def _text_rows(path: Path, text: str) -> dict[str, np.ndarray]:
    """The ``NAME: numbers`` lines of a calibration text file."""
    rows: dict[str, np.ndarray] = {}
    for line in text.splitlines():
        m = re.match(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*:\s*(.*)$", line)
        if m:
            try:
                rows[m.group(1)] = np.array(m.group(2).replace(",", " ").split(), dtype=np.float64)
            except ValueError:
                raise InputError(path, f"line {m.group(1)!r} is not numeric") from None
    return rows


def _opencalib_txt(path: Path, text: str) -> RigFile:
    rows = _text_rows(path, text)
    if "K" not in rows:
        raise InputError(path, "no 'K:' line (9 numbers, row-major)")
    K = _check_K(path, _matrix(path, rows["K"], (3, 3), "K"))
    D = _distortion(path, _vector(path, rows.get("D"), "D"), "radtan")
    seed = _extrinsic_from_matrix(path, rows["T"]) if "T" in rows else None
    return RigFile(K, D, "radtan", None, None, seed, path, "OpenCalib calib.txt")


#: A KITTI calib.txt: projection matrices ``P0:``..``P3:`` and the lidar transform.
KITTI_TEXT = re.compile(r"^\s*P[0-3]\s*:", re.MULTILINE)
KITTI_CAMERAS = ("P0", "P1", "P2", "P3")


def _kitti_txt(path: Path, text: str, camera: str | None = None) -> RigFile:
    """KITTI's ``calib.txt`` (odometry: ``P0..P3``, ``Tr``; object: also ``R0_rect``,
    ``Tr_velo_to_cam``): the rectified camera ``camera`` (default ``P2``, the left colour
    camera) with no distortion, and the lidar -> that camera as the seed: ``P = K [I | o]``
    gives ``T = [I | o] R0_rect Tr`` (``R0_rect`` the identity when absent)."""
    rows = _text_rows(path, text)
    name = camera or "P2"
    if name not in KITTI_CAMERAS:
        raise InputError(path, f"camera {name!r}: a KITTI calib.txt names P0, P1, P2 or P3")
    if name not in rows:
        raise InputError(path, f"no '{name}:' line (12 numbers, the 3x4 projection matrix)")
    P = _matrix(path, rows[name], (3, 4), name)
    K = _check_K(path, P[:, :3].copy())
    offset = np.linalg.solve(K, P[:, 3])
    seed = None
    tr = next((k for k in ("Tr_velo_to_cam", "Tr") if k in rows), None)
    if tr is not None:
        T = np.eye(4)
        T[:3] = _matrix(path, rows[tr], (3, 4), tr)
        R0 = np.eye(4)
        if "R0_rect" in rows:
            R0[:3, :3] = _matrix(path, rows["R0_rect"], (3, 3), "R0_rect")
        shift = np.eye(4)
        shift[:3, 3] = offset
        seed = _extrinsic_from_matrix(path, shift @ R0 @ T)
    return RigFile(K, np.zeros(5), "radtan", None, None, seed, path, f"KITTI calib.txt ({name})")


_READERS = [
    (_is_ours, _ours),
    (_is_reference, _reference),
    (_is_ros, _ros),
    (_is_kalibr, _kalibr),
    (_is_opencalib_intrinsic, _opencalib_intrinsic),
    (_is_opencv, _opencv),
]
