"""A corpus of bad inputs through the real CLI: each is exit 2, one stderr line naming the file or
option, no traceback; memory bombs stay under a peak-RSS bound.

Each case builds its input under ``tmp`` (a fresh folder holding ``scenes/``, a tiny valid scene
folder) and returns the command line and the fragments the error line must contain.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest
import yaml

from bad_inputs import assert_one_line_error, run_cli
from l2e_studio.synth import SynthConfig, config_with, write_dataset

TINY = config_with(SynthConfig(), n_scenes=2, width=320, height=180, points_per_scan=4000, seed=5)
#: Peak RSS a bad input may cost (the interpreter with numpy, scipy and OpenCV is about 100 MB).
RSS_BOUND_MB = 400

GOOD_K = [[300.0, 0, 160.0], [0, 300.0, 90.0], [0, 0, 1]]
SEED = {"translation": [0.0, 0.0, 0.0], "rotvec": [1.2091996, -1.2091996, 1.2091996]}


@pytest.fixture(scope="module")
def tiny_dir(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("tiny") / "scenes", TINY)


@pytest.fixture
def tmp(tiny_dir, tmp_path) -> Path:
    shutil.copytree(tiny_dir, tmp_path / "scenes", ignore=shutil.ignore_patterns(".l2e_cache"))
    return tmp_path


# --- builders ---------------------------------------------------------------------------------

def _camera_case(text: str | bytes, name: str = "camera.yaml") -> Callable[[Path], list]:
    def build(tmp: Path) -> list:
        f = tmp / name
        f.write_bytes(text if isinstance(text, bytes) else text.encode())
        return ["calibrate", "--scenes", tmp / "scenes", "--camera", f, "--quiet", "--out", tmp / "r.yaml"], f
    return build


def _seed_case(text: str | bytes, name: str = "seed.yaml") -> Callable[[Path], list]:
    def build(tmp: Path) -> list:
        f = tmp / name
        f.write_bytes(text if isinstance(text, bytes) else text.encode())
        return ["calibrate", "--scenes", tmp / "scenes", "--seed", f, "--quiet", "--out", tmp / "r.yaml"], f
    return build


def _option_case(*options: str) -> Callable[[Path], list]:
    def build(tmp: Path) -> list:
        return ["calibrate", "--scenes", tmp / "scenes", "--quiet", "--out", tmp / "r.yaml", *options], options[0]
    return build


def _ours(**camera) -> str:
    cam = {"model": "radtan", "width": 320, "height": 180, "K": GOOD_K, "D": [0, 0, 0, 0, 0], **camera}
    return yaml.safe_dump({"camera": cam, "seed": SEED})


def _alias_bomb() -> str:
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for i in range(1, 9):
        prev, cur = chr(ord("a") + i - 1), chr(ord("a") + i)
        lines.append(f"{cur}: &{cur} [" + ",".join([f"*{prev}"] * 9) + "]")
    lines.append("camera: {K: *i, width: 320, height: 180}")
    return "\n".join(lines) + "\n"


def _matrix_text(m) -> str:
    return "\n".join(" ".join(str(v) for v in row) for row in m) + "\n"


def _npy_header(shape: tuple) -> bytes:
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f4", "fortran_order": False, "shape": shape})
    return buf.getvalue()


SHEAR = [[1, 0.2, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
REFLECT = [[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]


CAMERA_CASES = {
    "yaml-alias-bomb": (_camera_case(_alias_bomb()), ["alias"]),
    "yaml-20k-levels": (_camera_case("camera: " + "[" * 20000 + "]" * 20000 + "\n"), ["nested"]),
    "yaml-20k-block-levels": (_camera_case("".join("  " * i + "a:\n" for i in range(2000)) + "  " * 2000 + "b\n"),
                              ["nested"]),
    "json-100k-levels": (_camera_case('{"cam": ' + "[" * 100000 + "]" * 100000 + "}", "config.json"), ["nested"]),
    "json-100k-objects": (_camera_case('{"a":' * 100000 + "1" + "}" * 100000, "config.json"), ["nested"]),
    "file-over-size-cap": (_camera_case("# " + "x" * (5 * 2**20) + "\n" + _ours()), ["MiB"]),
    "width-abc": (_camera_case(_ours(width="abc")), ["width", "abc"]),
    "width-negative": (_camera_case(_ours(width=-320)), ["width"]),
    "width-fraction": (_camera_case(_ours(width=320.5)), ["width"]),
    "width-huge": (_camera_case(_ours(width=10**9)), ["width"]),
    "height-list": (_camera_case(_ours(height=[180])), ["height"]),
    "kalibr-one-value-resolution": (_camera_case(yaml.safe_dump({"cam0": {
        "camera_model": "pinhole", "intrinsics": [300.0, 300.0, 160.0, 90.0], "distortion_model": "radtan",
        "distortion_coeffs": [0, 0, 0, 0], "resolution": [320]}})), ["resolution"]),
    "kalibr-string-resolution": (_camera_case(yaml.safe_dump({"cam0": {
        "camera_model": "pinhole", "intrinsics": [300.0, 300.0, 160.0, 90.0], "distortion_model": "radtan",
        "distortion_coeffs": [0, 0, 0, 0], "resolution": "320x180"}})), ["resolution"]),
    "kalibr-text-intrinsics": (_camera_case(yaml.safe_dump({"cam0": {
        "camera_model": "pinhole", "intrinsics": ["a", "b", "c", "d"], "resolution": [320, 180]}})), ["not numeric"]),
    "K-zero-focal": (_camera_case(_ours(K=[[0, 0, 160], [0, 300, 90], [0, 0, 1]])), ["focal"]),
    "K-singular-last-row": (_camera_case(_ours(K=[[300, 0, 160], [0, 300, 90], [0, 0, 0]])), ["pinhole"]),
    "K-transposed": (_camera_case(_ours(K=[[300, 0, 0], [0, 300, 0], [160, 90, 1]])), ["pinhole"]),
    "K-aspect-1000": (_camera_case(_ours(K=[[300000, 0, 160], [0, 300, 90], [0, 0, 1]])), ["not physical"]),
    "K-nan": (_camera_case(_ours(K=[[float("nan"), 0, 160], [0, 300, 90], [0, 0, 1]])), ["NaN"]),
    "K-ragged": (_camera_case(_ours(K=[[300, 0, 160], [0, 300], [0, 0, 1]])), ["camera.K"]),
    "K-strings": (_camera_case(_ours(K=[["a", 0, 160], [0, 300, 90], [0, 0, 1]])), ["not numeric"]),
    "K-principal-point-outside": (_camera_case(_ours(K=[[300, 0, 5000], [0, 300, 90], [0, 0, 1]])),
                                  ["principal point"]),
    "D-strings": (_camera_case(_ours(D="abc")), ["camera.D"]),
    "opencv-yaml-truncated": (_camera_case("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n"
                                           "   dt: d\n   data: [ 300., 0., 160.,"), ["camera.yaml"]),
    "opencv-yaml-2x2-matrix": (_camera_case("%YAML:1.0\n---\nimage_width: 320\nimage_height: 180\ncamera_matrix: "
                                            "!!opencv-matrix\n   rows: 2\n   cols: 2\n   dt: d\n   data: [ 1., 0., 0., 1. ]\n"),
                               ["camera_matrix must be 3x3"]),
    "ros-camera-info-text-K": (_camera_case(yaml.safe_dump({"image_width": 320, "image_height": 180, "camera_matrix": {
        "rows": 3, "cols": 3, "data": ["a"] * 9}, "distortion_model": "plumb_bob"})), ["not numeric"]),
    "reference-json-no-K": (_camera_case(json.dumps({"cam": {"D": [0, 0, 0, 0, 0]}}), "config.json"), ["cam.K"]),
    "unknown-distortion-model": (_camera_case(_ours(model="wobbly")), ["wobbly"]),
    "radtan-7-coefficients": (_camera_case(_ours(D=[0] * 7)), ["7"]),
    "not-utf8": (_camera_case(b"\xff\xfe\x00camera\x80\x81"), ["UTF-8"]),
    "empty": (_camera_case(""), ["empty"]),
    "top-level-list": (_camera_case("- 1\n- 2\n"), ["mapping"]),
    "invalid-yaml": (_camera_case("camera: {K: [1, 2\n"), ["YAML"]),
    "invalid-json": (_camera_case('{"cam": [1, 2', "config.json"), ["JSON"]),
    "unknown-format": (_camera_case("foo: 1\nbar: 2\n"), ["unknown camera file format"]),
}

SEED_CASES = {
    "seed-ragged-rows": (_seed_case(json.dumps([[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), "seed.json"),
                         ["rows differ"]),
    "seed-strings-in-matrix": (_seed_case(yaml.safe_dump({"T_cam_lidar": [["a", 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                                                          [0, 0, 0, 1]]})), ["not numeric"]),
    "seed-sheared": (_seed_case(_matrix_text(SHEAR), "seed.txt"), ["not a rotation"]),
    "seed-scaled": (_seed_case(_matrix_text(np.diag([2, 2, 2, 1]).tolist()), "seed.txt"), ["not a rotation"]),
    "seed-reflection": (_seed_case(_matrix_text(REFLECT), "seed.txt"), ["not a rotation"]),
    "seed-bad-last-row": (_seed_case(_matrix_text([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [1, 1, 1, 1]]),
                                     "seed.txt"), ["last row"]),
    "seed-nan": (_seed_case(_matrix_text([[1, 0, 0, "nan"], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), "seed.txt"),
                 ["NaN"]),
    "seed-translation-absurd": (_seed_case(_matrix_text([[1, 0, 0, 1e7], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
                                           "seed.txt"), ["kilometre"]),
    "seed-five-numbers": (_seed_case("1 2 3 4 5\n", "seed.txt"), ["12 or 16"]),
    "seed-words": (_seed_case("hello world\n", "seed.txt"), ["not a 4x4 matrix"]),
    "seed-alias-bomb": (_seed_case(_alias_bomb().replace("camera: {K: *i, width: 320, height: 180}",
                                                         "T_cam_lidar: *i")), ["alias"]),
    "seed-json-deep": (_seed_case("[" * 100000 + "]" * 100000, "seed.json"), ["nested"]),
    "seed-translation-2-values": (_seed_case(yaml.safe_dump({"translation": [0, 0], "rotvec": [0, 0, 0]})),
                                  ["seed translation"]),
    "seed-rotvec-text": (_seed_case(yaml.safe_dump({"translation": [0, 0, 0], "rotvec": "up"})), ["seed rotvec"]),
    "seed-zero-quaternion": (_seed_case(yaml.safe_dump({"translation": [0, 0, 0], "quaternion_xyzw": [0, 0, 0, 0]})),
                             ["seed"]),
    "seed-quaternion-norm-2": (_seed_case(yaml.safe_dump({"translation": [0, 0, 0], "quaternion_xyzw": [0, 0, 0, 2]})),
                               ["norm 2"]),
    "seed-no-rotation": (_seed_case(yaml.safe_dump({"translation": [0, 0, 0]})), ["no rotvec"]),
    "seed-npy-object": (lambda tmp: _npy_seed(tmp, np.array([[1, "a"]], dtype=object)), [".npy"]),
    "seed-npy-header-lies": (_seed_case(_npy_header((4, 4)) + bytes(8), "seed.npy"), ["header declares"]),
    "seed-npy-3x3": (lambda tmp: _npy_seed(tmp, np.eye(3)), ["4x4 or 3x4"]),
    "seed-over-size-cap": (_seed_case("# " + "x" * (5 * 2**20) + "\n" + _matrix_text(np.eye(4).tolist()), "seed.txt"),
                           ["MiB"]),
    "seed-missing": (lambda tmp: (["calibrate", "--scenes", tmp / "scenes", "--seed", tmp / "nope.yaml", "--quiet"],
                                  tmp / "nope.yaml"), ["does not exist"]),
}


def _npy_seed(tmp: Path, arr: np.ndarray):
    f = tmp / "seed.npy"
    np.save(f, arr, allow_pickle=True)
    return ["calibrate", "--scenes", tmp / "scenes", "--seed", f, "--quiet", "--out", tmp / "r.yaml"], f


#: Paths that are not regular files: refused before they are opened (a FIFO or /dev/zero never ends).
SPECIAL_FILE_CASES = {
    "seed-fifo": (lambda tmp: (["calibrate", "--scenes", tmp / "scenes", "--seed", _fifo(tmp), "--quiet"],
                               tmp / "fifo.yaml"), ["not a regular file"]),  # reading it would block forever
    "camera-dev-zero": (lambda tmp: (["calibrate", "--scenes", tmp / "scenes", "--camera", "/dev/zero", "--quiet"],
                                     "/dev/zero"), ["not a regular file"]),  # reading it would never end
    "seed-folder": (lambda tmp: (["calibrate", "--scenes", tmp / "scenes", "--seed", tmp / "scenes", "--quiet"],
                                 tmp / "scenes"), ["not a regular file"]),
}

OPTION_CASES = {
    "bound-m-1e9": (_option_case("--bound-m", "1e9"), ["--bound-m"]),
    "bound-m-nan": (_option_case("--bound-m", "nan"), ["--bound-m"]),
    "bound-m-inf": (_option_case("--bound-m", "inf"), ["--bound-m"]),
    "bound-m-negative": (_option_case("--bound-m", "-0.1"), ["--bound-m"]),
    "bound-deg-zero": (_option_case("--bound-deg", "0"), ["--bound-deg"]),
    "bound-deg-1000": (_option_case("--bound-deg", "1000"), ["--bound-deg"]),
    "bound-deg-nan": (_option_case("--bound-deg", "nan"), ["--bound-deg"]),
    "sigma-nan": (_option_case("--sigma", "nan"), ["--sigma"]),
    "sigma-1e6": (_option_case("--sigma", "1e6"), ["--sigma"]),
    "sigma-inf": (_option_case("--sigma", "inf"), ["--sigma"]),
    "sigma-negative": (_option_case("--sigma", "-1"), ["--sigma"]),
}

def _out_case(make: Callable[[Path], Path], *extra: str) -> Callable[[Path], list]:
    def build(tmp: Path) -> list:
        out = make(tmp)
        return ["calibrate", "--scenes", tmp / "scenes", "--quiet", "--out", out, *extra], out
    return build


def _fifo(tmp: Path) -> Path:
    os.mkfifo(tmp / "fifo.yaml")
    return tmp / "fifo.yaml"


def _device(tmp: Path) -> Path:
    """A private character device like /dev/null (a regression replaces this one, not the real one)."""
    try:
        os.mknod(tmp / "null", stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError:
        pytest.skip("creating a device node needs root")
    return tmp / "null"


def _symlink(tmp: Path, target: str = "real.yaml") -> Path:
    (tmp / "link.yaml").symlink_to(tmp / target)
    if target == "real.yaml":
        (tmp / target).write_text("old: 1\n")
    return tmp / "link.yaml"


def _file_parent(tmp: Path) -> Path:
    (tmp / "afile").write_text("x")
    return tmp / "afile" / "sub" / "r.yaml"


OUTPUT_CASES = {
    "out-device": (_out_case(lambda tmp: _device(tmp)), ["device"]),
    "out-fifo": (_out_case(_fifo), ["FIFO"]),
    "out-folder": (_out_case(lambda tmp: tmp / "scenes"), ["folder"]),
    "out-symlink": (_out_case(_symlink), ["symbolic link"]),
    "out-dangling-symlink": (_out_case(lambda tmp: _symlink(tmp, "missing.yaml")), ["symbolic link"]),
    "out-parent-is-file": (_out_case(_file_parent), ["is a file"]),
}

def _scene_case(damage: Callable[[Path], Path], *extra: str) -> Callable[[Path], list]:
    """Damage every scene of the copy the same way; ``damage`` returns the path the line must name."""
    def build(tmp: Path) -> list:
        named = damage(tmp / "scenes")
        return ["calibrate", "--scenes", tmp / "scenes", "--quiet", "--out", tmp / "r.yaml", *extra], named
    return build


def _maps(folder: Path, value: int) -> Path:
    for f in sorted((folder / "event").glob("*.png")):
        cv2.imwrite(str(f), np.full((TINY.height, TINY.width), value, np.uint8))
    return folder / "event" / "scene_000.png"


def _intensities(folder: Path, value: float) -> Path:
    for f in sorted((folder / "lidar").glob("*.txt")):
        table = np.loadtxt(f, delimiter=",")
        table[:, 3] = value
        np.savetxt(f, table, delimiter=",", fmt="%.4f")
    return folder / "lidar" / "scene_000.txt"


def _kitti(folder: Path, data: Callable[[int], bytes]) -> Path:
    for i, f in enumerate(sorted((folder / "lidar").glob("*.txt"))):
        f.unlink()
        (folder / "lidar" / f"{f.stem}.bin").write_bytes(data(i))
    return folder / "lidar" / "scene_000.bin"


def _seed_file(folder: Path, ext) -> Path:
    f = folder.parent / "seed.yaml"
    f.write_text(yaml.safe_dump({"translation": ext.translation.tolist(), "rotvec": ext.rotvec.tolist()}))
    return f


def _far_seed(folder: Path) -> Path:
    from l2e_studio.synth import read_truth

    truth = read_truth(folder / "truth.yaml")
    return _seed_file(folder, truth.perturbed([100.0, 0, 0], [0, 0, 0]))  # 100 m sideways


def _behind_seed(folder: Path) -> Path:
    from l2e_studio.geometry import Extrinsic
    from l2e_studio.synth import read_truth

    truth = read_truth(folder / "truth.yaml")
    return _seed_file(folder, Extrinsic.from_rpy([0, 180, 0], [0, 0, 0]).compose(truth))


def _corrupt_maps(folder: Path) -> Path:
    for f in sorted((folder / "event").glob("*.png")):
        f.write_bytes(f.read_bytes()[:100])
    return folder / "event" / "scene_000.png"


def _png_declaring(width: int, height: int) -> bytes:
    """A tiny, well-formed PNG header declaring ``width`` x ``height`` 8-bit grey pixels (few rows of data)."""
    import struct
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(bytes(width + 1) * 4)) + \
        chunk(b"IEND", b"")


def _png_maps(width: int, height: int) -> Callable[[Path], Path]:
    def damage(folder: Path) -> Path:
        for f in sorted((folder / "event").glob("*.png")):
            f.write_bytes(_png_declaring(width, height))
        return folder / "event" / "scene_000.png"
    return damage


def _twin_scans(folder: Path) -> Path:
    for f in sorted((folder / "lidar").glob("*.txt")):
        shutil.copy(f, f.with_suffix(".csv"))
    return folder / "lidar" / "scene_000.csv"


def _twin_maps(folder: Path) -> Path:
    for f in sorted((folder / "event").glob("*.png")):
        np.save(f.with_suffix(".npy"), cv2.imread(str(f), cv2.IMREAD_UNCHANGED).astype(np.float32))
    return folder / "event" / "scene_000.npy"


def _scans(write: Callable[[Path, int], Path]) -> Callable[[Path], Path]:
    """Replace every scan of the folder by ``write(lidar_dir / stem, i)``; name the first."""
    def damage(folder: Path) -> Path:
        named = None
        for i, f in enumerate(sorted((folder / "lidar").glob("*.txt"))):
            f.unlink()
            out = write(folder / "lidar" / f.stem, i)
            named = named or out
        return named
    return damage


PCD_HEAD = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
            "WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {kind}\n")


def _pcd(stem: Path, n: int, kind: str, body: bytes) -> Path:
    path = stem.with_suffix(".pcd")
    path.write_bytes(PCD_HEAD.format(n=n, kind=kind).encode() + body)
    return path


def _pcd_bomb(stem: Path, i: int) -> Path:
    n = 2**26  # 1 GiB of points declared in a ~250-byte file
    return _pcd(stem, n, "binary_compressed", np.array([100, 16 * n], "<u4").tobytes() + bytes(100))


def _write(suffix: str, data: bytes) -> Callable[[Path, int], Path]:
    def write(stem: Path, i: int) -> Path:
        path = stem.parent / (stem.name + suffix)
        path.write_bytes(data)
        return path
    return write


def _npy(arr: np.ndarray, suffix: str = ".npy") -> Callable[[Path, int], Path]:
    def write(stem: Path, i: int) -> Path:
        path = stem.parent / (stem.name + suffix)
        np.save(path, arr, allow_pickle=True) if suffix == ".npy" else np.savez(path, foo=arr)
        return path
    return write


def _las_bomb(stem: Path, i: int) -> Path:
    import struct

    import laspy

    header = laspy.LasHeader(point_format=1, version="1.2")
    las = laspy.LasData(header)
    las.x, las.y, las.z = RNG.uniform(1, 10, (3, 100))
    path = stem.with_suffix(".las")
    las.write(path)
    data = bytearray(path.read_bytes())
    data[107:111] = struct.pack("<I", 2**31)  # 2 billion points declared in a ~3 kB file
    path.write_bytes(bytes(data))
    return path


PLY_HEAD = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\nproperty float x\nproperty float y\n" \
           b"property float z\nproperty float intensity\nend_header\n"

RNG = np.random.default_rng(1)
SCENE_CASES = {
    "pcd-compressed-bomb": (_scene_case(_scans(_pcd_bomb)), ["binary_compressed"]),
    "pcd-binary-truncated": (_scene_case(_scans(lambda st, i: _pcd(st, 10**8, "binary", bytes(64)))), ["truncated"]),
    "pcd-no-data-line": (_scene_case(_scans(_write(".pcd", b"# .PCD v0.7\nFIELDS x y z\n" * 30))), ["DATA"]),
    "pcd-ascii-garbage": (_scene_case(_scans(lambda st, i: _pcd(st, 3, "ascii", b"a b c d\n1 2\n"))), [".pcd"]),
    "pcd-unknown-encoding": (_scene_case(_scans(lambda st, i: _pcd(st, 3, "zip", b"xx"))), ["encoding"]),
    "las-declares-2e9-points": (_scene_case(_scans(_las_bomb)), ["declares 2147483648 points"]),
    "laz-random-bytes": (_scene_case(_scans(_write(".laz", RNG.bytes(3000)))), [".laz"]),
    "ply-billion-vertices": (_scene_case(_scans(_write(".ply", PLY_HEAD + bytes(160)))), [".ply"]),
    "ply-not-ply": (_scene_case(_scans(_write(".ply", b"plx\nrandom\n"))), [".ply"]),
    "npy-object-array": (_scene_case(_scans(_npy(np.array([{"a": 1}], dtype=object)))), [".npy"]),
    "npy-header-declares-8-GB": (_scene_case(_scans(_write(".npy", _npy_header((500_000_000, 4)) + bytes(64)))),
                                 ["header declares"]),
    "npy-1d": (_scene_case(_scans(_npy(np.arange(10.0)))), [".npy"]),
    "npz-no-points": (_scene_case(_scans(_npy(np.arange(10.0), ".npz"))), [".npz"]),
    "txt-words": (_scene_case(_scans(_write(".txt", b"hello world\nfoo bar\n"))), [".txt"]),
    "txt-binary": (_scene_case(_scans(_write(".txt", RNG.bytes(2000)))), [".txt"]),
    "txt-no-intensity": (_scene_case(_scans(_write(".txt", b"1,2,3\n4,5,6\n7,8,9\n"))), ["intensity"]),
    "txt-all-nan": (_scene_case(_scans(_write(".txt", b"nan,nan,nan,1\n" * 10))), ["valid"]),
    "png-corrupt": (_scene_case(lambda d: _corrupt_maps(d)), [".png"]),
    "png-declares-50000-squared": (_scene_case(_png_maps(50000, 50000)), ["50000x50000"]),
    "png-declares-16000-squared": (_scene_case(_png_maps(16000, 16000)), ["16000x16000", "320x180"]),
    "maps-all-zero": (_scene_case(lambda d: _maps(d, 0)), ["constant"]),
    "maps-constant": (_scene_case(lambda d: _maps(d, 40)), ["constant"]),
    "intensities-all-zero": (_scene_case(lambda d: _intensities(d, 0.0)), ["intensities are equal"]),
    "intensities-constant": (_scene_case(lambda d: _intensities(d, 77.0)), ["intensities are equal"]),
    "kitti-random-bytes": (_scene_case(lambda d: _kitti(d, lambda i: RNG.bytes(16 * 5000))), ["not a float32"]),
    "kitti-size-not-16": (_scene_case(lambda d: _kitti(d, lambda i: RNG.bytes(16 * 5000 + 7))), ["multiple of 16"]),
    "kitti-all-nan": (_scene_case(lambda d: _kitti(d, lambda i: np.full((100, 4), np.nan, "<f4").tobytes())),
                      ["NaN"]),
    "seed-100-m-off": (_scene_case(lambda d: _far_seed(d), "--seed", "SEED"), ["land in the", "far off"]),
    "seed-cloud-behind-camera": (_scene_case(lambda d: _behind_seed(d), "--seed", "SEED"), ["behind the camera"]),
    "two-scans-one-stem": (_scene_case(_twin_scans), ["share the stem"]),
    "two-maps-one-stem": (_scene_case(_twin_maps), ["share the stem"]),
}

def _events_case(name: str, make: Callable[[], bytes | dict], *options: str,
                 names_option: bool = False) -> Callable[[Path], list]:
    """One recording in ``ev/events_raw/`` (a dict is saved as .npz), run through ``accumulate``."""
    def build(tmp: Path) -> list:
        raw = tmp / "ev" / "events_raw"
        raw.mkdir(parents=True)
        data = make()
        if isinstance(data, dict):
            np.savez(raw / name, **data)
        else:
            (raw / name).write_bytes(data)
        return ["accumulate", tmp / "ev", *options], (options[0] if names_option else raw / name)
    return build


def _events(n: int = 20000, width: int = 320, height: int = 180, **change) -> dict:
    rng = np.random.default_rng(2)
    ev = {"x": rng.integers(0, width, n), "y": rng.integers(0, height, n), "t": np.sort(rng.integers(0, 2_000_000, n)),
          "p": rng.integers(0, 2, n), "sensor_size": np.array([width, height])}
    for key, fn in change.items():
        ev[key] = fn(ev[key])
    return ev


def _backward_jump(t: np.ndarray) -> np.ndarray:
    t = t.copy()
    t[len(t) // 2:] -= 1_000_000
    return t


def _with_nan(a: np.ndarray) -> np.ndarray:
    a = a.astype(np.float64)
    a[7] = np.nan
    return a


def _evt2(width: int, height: int, n: int = 5000, max_x: int | None = None) -> bytes:
    from l2e_studio.io.event_prophesee import encode_evt2

    rng = np.random.default_rng(3)
    x = rng.integers(0, max_x or width, n)
    return encode_evt2(x, rng.integers(0, height, n), np.sort(rng.integers(0, 1_000_000, n)), rng.integers(0, 2, n),
                       width, height)


def _dat_bomb() -> bytes:
    from l2e_studio.io.event_prophesee import encode_dat

    return encode_dat([16383, 0], [16383, 0], [0, 10], [1, 0])  # 63 bytes, no sensor size


def _camera_yaml_for_events(tmp_make):
    def build(tmp: Path) -> list:
        args, named = tmp_make(tmp)
        (tmp / "ev" / "camera.yaml").write_text(_ours())
        return args, named
    return build


def _accumulate_into_file(tmp: Path) -> tuple[list, Path]:
    """``event`` is a file where accumulate writes its PNG maps: the write fails after decoding."""
    args, _ = _events_case("a.npz", _events)(tmp)
    (tmp / "ev" / "event").write_text("not a folder")
    return args, tmp / "ev" / "event"


def _random_file(path: Path) -> Path:
    path.write_bytes(RNG.bytes(4096))
    return path


def _h5(write: Callable) -> Callable[[Path], list]:
    """An HDF5 recording in ``ev/events_raw/a.h5`` written by ``write(h5py.File)``, through ``accumulate``."""
    def build(tmp: Path) -> list:
        import h5py

        raw = tmp / "ev" / "events_raw"
        raw.mkdir(parents=True)
        with h5py.File(raw / "a.h5", "w") as f:
            write(f)
        return ["accumulate", tmp / "ev"], raw / "a.h5"
    return build


def _h5_events(f, n: int = 1000, **change) -> None:
    ev = _events(n)
    ev.pop("sensor_size")
    ev.update(change)
    g = f.create_group("events")
    for k, v in ev.items():
        g.create_dataset(k, data=v)


def _h5_sized(f) -> None:
    _h5_events(f)
    f["events"].attrs["width"], f["events"].attrs["height"] = 10**6, 10**6


EVENT_CASES = {
    "h5-random-bytes": (_events_case("a.h5", lambda: RNG.bytes(5000)), ["HDF5"]),
    "h5-lengths-differ": (_h5(lambda f: _h5_events(f, x=np.arange(10))), ["different lengths"]),
    "h5-only-x-y": (_h5(lambda f: f.create_group("events").create_dataset("x", data=np.arange(5))), ["no events"]),
    "h5-string-coordinates": (_h5(lambda f: _h5_events(f, x=np.array([b"a"] * 1000))), ["a.h5"]),
    "h5-huge-sensor-attrs": (_h5(_h5_sized), ["at most"]),
    "h5-time-backwards": (_h5(lambda f: _h5_events(f, t=np.arange(1000)[::-1] * 10_000)), ["backwards"]),
    "events-reversed": (_events_case("a.npz", lambda: _events(t=lambda t: t[::-1].copy())), ["backwards"]),
    "events-backward-jump": (_events_case("a.npz", lambda: _events(t=_backward_jump)), ["backwards"]),
    "events-nan-time": (_events_case("a.npz", lambda: _events(t=lambda t: _with_nan(t / 1e6))), ["NaN"]),
    "events-nan-x": (_events_case("a.npz", lambda: _events(x=_with_nan)), ["NaN"]),
    "events-fractional-y": (_events_case("a.npz", lambda: _events(y=lambda y: y + 0.5)), ["fractional"]),
    "events-negative-x": (_events_case("a.npz", lambda: _events(x=lambda x: x - 5)), ["negative"]),
    "events-outside-declared-sensor": (_events_case("a.npz", lambda: _events(x=lambda x: x * 3)), ["outside the 320x180"]),
    "events-header-larger-than-camera": (_camera_yaml_for_events(_events_case("a.raw", lambda: _evt2(1280, 720))),
                                         ["1280x720 sensor but the camera is 320x180"]),
    "events-size-option-disagrees": (_events_case("a.raw", lambda: _evt2(640, 480), "--size", "320x240"),
                                     ["640x480 sensor but the camera is 320x240"]),
    "events-header-huge-sensor": (_events_case("a.raw", lambda: _evt2(100000, 100000, max_x=100)), ["at most"]),
    "events-dat-63-bytes": (_events_case("a.dat", _dat_bomb), ["beyond any event sensor"]),
    "events-raw-random-bytes": (_events_case("a.raw", lambda: RNG.bytes(4096)), ["a.raw"]),
    "events-npz-no-arrays": (_events_case("a.npz", lambda: {"foo": np.arange(3)}), ["a.npz"]),
    "extract-window-nan": (lambda tmp: (["extract", tmp / "x.bag", "--out", tmp / "o", "--window", "nan"], "--window"),
                           ["--window"]),
    "extract-slice-zero": (lambda tmp: (["extract", tmp / "x.bag", "--out", tmp / "o", "--slice", "0"], "--slice"),
                           ["--slice"]),
    "extract-scans-zero": (lambda tmp: (["extract", tmp / "x.bag", "--out", tmp / "o", "--scans", "0"], "--scans"),
                           ["--scans"]),
    "extract-out-is-a-file": (lambda tmp: (["extract", tmp / "x.bag", "--out", tmp / "scenes" / "camera.yaml"],
                                           tmp / "scenes" / "camera.yaml"), ["not a folder"]),
    "accumulate-event-dir-is-a-file": (_accumulate_into_file, ["event"]),
    "synth-parent-is-a-file": (lambda tmp: (["synth", "--out", tmp / "scenes" / "camera.yaml" / "new", "--preset", "sample"],
                                            tmp / "scenes" / "camera.yaml"), ["is a file"]),
    "aedat4-random-bytes": (_events_case("a.aedat4", lambda: RNG.bytes(4096)), ["a.aedat4"]),
    "events-txt-words": (_events_case("a.txt", lambda: b"t x y p\nsoon left up on\n" * 10), ["a.txt"]),
    "events-txt-negative-y": (_events_case("a.txt", lambda: b"0.1 5 -3 1\n0.2 6 4 0\n"), ["a.txt"]),
    "extract-random-bytes-bag": (lambda tmp: (["extract", _random_file(tmp / "x.bag"), "--out", tmp / "o"],
                                              tmp / "x.bag"), ["x.bag"]),
    "extract-missing-bag": (lambda tmp: (["extract", tmp / "nope.bag", "--out", tmp / "o"], tmp / "nope.bag"),
                            ["nope.bag"]),
    "events-window-nan": (_events_case("a.npz", _events, "--window", "nan", names_option=True), ["--window"]),
    "events-window-negative": (_events_case("a.npz", _events, "--window", "-3", names_option=True), ["--window"]),
    "events-window-1e12": (_events_case("a.npz", _events, "--window", "1e12", names_option=True), ["--window"]),
    "events-start-inf": (_events_case("a.npz", _events, "--start", "inf", names_option=True), ["--start"]),
    "events-hot-pixels-nan": (_events_case("a.npz", _events, "--hot-pixels", "nan", names_option=True), ["--hot-pixels"]),
    "events-size-huge": (_events_case("a.npz", _events, "--size", "100000x100000", names_option=True), ["100000x100000"]),
    "events-start-past-end": (_events_case("a.npz", _events, "--start", "100"), ["no events in the window"]),
}

def _serve_case(*options: str, out_file: bool = False) -> Callable[[Path], list]:
    def build(tmp: Path) -> list:
        extra = []
        if out_file:
            (tmp / "taken").write_text("x")
            extra = ["--out", tmp / "taken"]
        return ["--scenes", tmp / "scenes", *options, *extra], options[0] if options else tmp / "taken"
    return build


SERVE_CASES = {
    "serve-host-unresolvable": (_serve_case("--host", "no-such-host.invalid"), ["does not resolve"]),
    "serve-host-bad-address": (_serve_case("--host", "256.1.1.1"), ["does not resolve"]),
    "serve-port-0": (_serve_case("--port", "0"), ["1..65535"]),
    "serve-out-is-a-file": (_serve_case(out_file=True), ["not a folder"]),
    "synth-out-is-a-file": (lambda tmp: (["synth", "--out", tmp / "scenes" / "camera.yaml", "--preset", "sample"],
                                         tmp / "scenes" / "camera.yaml"), ["not a folder"]),
    "synth-out-not-empty": (lambda tmp: (["synth", "--out", tmp / "scenes", "--preset", "sample"], tmp / "scenes"),
                            ["not empty"]),
}

ALL_CASES = {**SERVE_CASES, **SPECIAL_FILE_CASES, **CAMERA_CASES, **SEED_CASES, **OPTION_CASES, **OUTPUT_CASES, **SCENE_CASES, **EVENT_CASES}


@pytest.mark.parametrize("name", sorted(ALL_CASES))
def test_bad_input_is_one_line_exit_2(name: str, tmp: Path) -> None:
    build, fragments = ALL_CASES[name]
    args, named = build(tmp)
    args = [named if a == "SEED" else a for a in args]
    run = run_cli(*args, cwd=tmp)
    assert_one_line_error(run, str(named), *fragments)
    assert run.peak_rss_mb < RSS_BOUND_MB, f"{name}: peak RSS {run.peak_rss_mb:.0f} MB"
    assert not (tmp / "r.yaml").exists()


def test_special_outputs_are_left_alone(tmp: Path) -> None:
    fifo, link = _fifo(tmp), _symlink(tmp)
    for out in (fifo, link):
        assert_one_line_error(run_cli("calibrate", "--scenes", tmp / "scenes", "--quiet", "--out", out, cwd=tmp))
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and link.is_symlink()
    assert (tmp / "real.yaml").read_text() == "old: 1\n"


def test_unwritable_output_keeps_the_result(tmp: Path) -> None:
    """The output fails after the optimisation (/proc takes no new files, even as root): the
    result goes to a named fallback file, the line says where, exit 2."""
    from l2e_studio.io.cameras import load_seed

    target = Path("/proc/l2e_studio_result.yaml")
    run = run_cli("calibrate", "--scenes", tmp / "scenes", "--quiet", "--single-stage", "--out", target, cwd=tmp)
    line = assert_one_line_error(run, str(target), "cannot write the result", "saved to")
    saved = Path(line.rsplit("saved to ", 1)[1])
    assert saved.parent == tmp and saved.name.startswith("l2e_studio_result.unsaved-") and saved.suffix == ".yaml"
    assert load_seed(saved).error_to(load_seed(tmp / "scenes" / "camera.yaml"))[0] < 5  # a real result
    assert "T_cam_lidar" in yaml.safe_load(saved.read_text())


def test_unresolvable_host_fails_within_seconds(tmp: Path) -> None:
    run = run_cli("--host", "no-such-host.invalid", "--scenes", tmp / "scenes", cwd=tmp)
    assert_one_line_error(run, "--host")
    assert run.seconds < 15


def test_non_loopback_host_prints_a_warning_with_the_real_url(tmp: Path, monkeypatch, capsys) -> None:
    import l2e_studio.app.server as server_module
    from l2e_studio.cli import main

    class FakeApp:
        url = "http://127.0.0.1:8123"
        server = type("S", (), {"get_port": staticmethod(lambda: 8123)})()

    monkeypatch.setattr(server_module, "serve", lambda scene_set, host, port, out_dir, on_ready, **kw: on_ready(FakeApp()))
    assert main(["--host", "0.0.0.0", "--port", "8123", "--scenes", str(tmp / "scenes"), "--out", str(tmp / "o")]) == 0
    err = capsys.readouterr().err
    assert "warning: --host 0.0.0.0 exposes the workbench" in err and ":8123" in err and str(tmp / "o") in err
    assert f"http://{_outbound()}:8123 can use it" in err  # the address other machines reach, not 127.0.0.1
    monkeypatch.setattr(server_module, "serve", lambda scene_set, host, port, out_dir, on_ready, **kw: on_ready(FakeApp()))
    assert main(["--port", "8123", "--scenes", str(tmp / "scenes"), "--out", str(tmp / "o")]) == 0
    assert "warning" not in capsys.readouterr().err


def _outbound() -> str:
    import socket

    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.connect(("192.0.2.1", 9))
            return probe.getsockname()[0]
    except OSError:
        return socket.gethostname()


@pytest.mark.parametrize("message, mi", [("Inequality constraints incompatible", 0.5),
                                         ("Singular matrix E in LSQ subproblem", 0.5),
                                         ("Optimization terminated successfully", float("nan"))])
def test_a_failing_optimiser_is_an_error_not_a_result(tmp: Path, monkeypatch, capsys, message, mi) -> None:
    import dataclasses

    import l2e_studio.calibrate as engine
    from l2e_studio.cli import main

    real = engine.calibrate

    def broken(*args, **kwargs):
        return dataclasses.replace(real(*args, **kwargs), message=message, score_result=mi)

    monkeypatch.setattr(engine, "calibrate", broken)
    code = main(["calibrate", "--scenes", str(tmp / "scenes"), "--single-stage", "--quiet", "--out", str(tmp / "r.yaml")])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert code == 2 and len(err) == 1 and "the optimiser failed" in err[0]
    assert not (tmp / "r.yaml").exists()
    monkeypatch.setattr(engine, "calibrate", real)
    assert main(["calibrate", "--scenes", str(tmp / "scenes"), "--single-stage", "--quiet",
                 "--out", str(tmp / "r.yaml")]) == 0


@pytest.mark.parametrize("name", sorted(n for n in SEED_CASES if n not in ("seed-missing",)))
def test_the_app_upload_path_refuses_the_same_seeds(name: str, tmp: Path) -> None:
    """The browser's seed upload parses with the same loaders: the same bad files are one
    InputError line naming the upload (what the app shows as a notification), nothing else."""
    from l2e_studio.app.files import seed_from_upload
    from l2e_studio.errors import InputError

    build, fragments = SEED_CASES[name]
    _, path = build(tmp)
    with pytest.raises(InputError) as info:
        seed_from_upload(path.name, path.read_bytes())
    line = str(info.value)
    assert line.startswith(path.name + ": ") and "\n" not in line
    for frag in fragments:
        assert frag in line


def test_a_huge_upload_is_refused_before_parsing() -> None:
    from l2e_studio.app.files import seed_from_upload
    from l2e_studio.errors import InputError

    with pytest.raises(InputError, match="big.yaml: is 200.0 MiB"):
        seed_from_upload("big.yaml", b"#" * (200 * 2**20))


def test_kill_9_during_calibrate_keeps_a_complete_result(tmp: Path) -> None:
    """calibrate killed at several moments: the result file is always the old or a new complete
    one, and the next run leaves no temporary file behind."""
    import signal
    import subprocess
    import sys
    import time

    from l2e_studio.atomic import temporaries
    from l2e_studio.io.cameras import load_seed

    out = tmp / "r.yaml"
    args = [sys.executable, "-m", "l2e_studio", "calibrate", "--scenes", str(tmp / "scenes"), "--quiet",
            "--single-stage", "--out", str(out)]
    assert subprocess.run(args, capture_output=True, timeout=120).returncode == 0
    for delay in (0.3, 0.8, 1.3, 1.8, 2.5):
        proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        for f in [out, *tmp.glob("r.*.bak.yaml")]:
            load_seed(f)  # every result and backup parses: none is half written
    assert subprocess.run(args, capture_output=True, timeout=120).returncode == 0
    assert temporaries(out) == []
