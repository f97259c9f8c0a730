"""Every reader against damaged copies of a small valid file (truncated at every offset, bytes
flipped, headers lying): each case loads a result the reader's promises hold for, or raises the
one InputError line naming the file; never another exception, never memory beyond the file's size.

Deterministic (fixed seeds) and bounded: up to ~300 cases a reader (fewer for bags, slow to
open), a few seconds each on a quiet machine.
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import yaml

from conftest import REALDATA
from bag_files import write_bag
from fuzz_inputs import Target, run_target
from l2e_studio.limits import MAX_EVENT_SENSOR_SIDE

RNG = np.random.default_rng(7)
N = 40
PTS = np.column_stack([RNG.uniform(-20, 20, (N, 3)), RNG.integers(0, 255, N)]).astype(np.float32)
W, H = 48, 32
EV = dict(x=RNG.integers(0, W, 300), y=RNG.integers(0, H, 300), t=np.sort(RNG.integers(0, 400_000, 300)),
          p=RNG.integers(0, 2, 300))


# --- checks: what a successful read promises ------------------------------------------------

def check_scan(scan) -> None:
    from l2e_studio.io.lidar import MAX_RANGE_M

    assert scan.points.ndim == 2 and scan.points.shape[1] == 3 and len(scan) > 0
    assert scan.intensity.shape == (len(scan),)
    assert np.all(np.isfinite(scan.points)) and np.abs(scan.points).max() <= MAX_RANGE_M
    assert np.all((scan.intensity >= 0) & (scan.intensity <= 255))


def check_events(result) -> None:
    size, chunks = result
    assert size is None or all(0 < v <= MAX_EVENT_SENSOR_SIDE for v in size)
    for c in chunks:
        assert c.x.dtype == np.uint16 and c.y.dtype == np.uint16 and c.t_us.dtype == np.int64 and c.p.dtype == np.uint8
        assert len(c.x) == len(c.y) == len(c.t_us) == len(c.p)


def check_map(result) -> None:
    image, kind = result
    assert image.ndim == 2 and image.size and image.dtype == np.float32 and kind in ("events", "image")
    assert np.all(np.isfinite(image)) and image.min() >= 0


def check_rig(rig) -> None:
    if rig.width and rig.height:
        cam = rig.camera()
        assert np.all(np.isfinite(cam.K))
    if rig.seed is not None:
        check_seed(rig.seed)


def check_seed(ext) -> None:
    assert np.all(np.isfinite(ext.matrix))


# --- loaders ----------------------------------------------------------------------------------

def load_scan(path: Path):
    from l2e_studio.io.lidar import load_lidar

    return load_lidar(path)


def load_events(path: Path):
    from l2e_studio.io.events import iter_events, sensor_size

    return sensor_size(path), list(iter_events(path, chunk_size=128))


def load_map_file(path: Path):
    from l2e_studio.io.maps import load_map

    return load_map(path, cache=False)


def load_rig_file(path: Path):
    from l2e_studio.io.cameras import load_rig

    return load_rig(path)


def load_seed_file(path: Path):
    from l2e_studio.io.cameras import load_seed

    return load_seed(path)


# --- valid files --------------------------------------------------------------------------------

def _text_scan() -> bytes:
    return b"x,y,z,intensity\n" + "".join(f"{a:.3f},{b:.3f},{c:.3f},{d:.0f}\n" for a, b, c, d in PTS).encode()


PCD = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n" \
      "WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {kind}\n"


def _pcd(kind: str) -> bytes:
    from l2e_studio.io import _lzf

    head = PCD.format(n=N, kind=kind).encode()
    if kind == "ascii":
        return head + "".join(f"{a:.3f} {b:.3f} {c:.3f} {d:.0f}\n" for a, b, c, d in PTS).encode()
    if kind == "binary":
        return head + PTS.astype("<f4").tobytes()
    raw = np.ascontiguousarray(PTS.T).astype("<f4").tobytes()  # column-major
    packed = _lzf.compress(raw)
    return head + struct.pack("<II", len(packed), len(raw)) + packed


PLY = "ply\nformat {fmt} 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n" \
      "property float intensity\nend_header\n"


def _ply(fmt: str) -> bytes:
    head = PLY.format(fmt=fmt, n=N).encode()
    if fmt == "ascii":
        return head + "".join(f"{a:.3f} {b:.3f} {c:.3f} {d:.0f}\n" for a, b, c, d in PTS).encode()
    return head + PTS.astype("<f4" if fmt == "binary_little_endian" else ">f4").tobytes()


def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def _npz(compressed: bool = False, **arrays) -> bytes:
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return buf.getvalue()


def _las(suffix: str) -> bytes:
    import laspy

    las = laspy.LasData(laspy.LasHeader(point_format=1, version="1.2"))
    las.x, las.y, las.z = PTS[:, 0].astype(float), PTS[:, 1].astype(float), PTS[:, 2].astype(float)
    las.intensity = PTS[:, 3].astype(np.uint16)
    buf = io.BytesIO()
    las.write(buf, do_compress=suffix == ".laz")
    return buf.getvalue()


def _raw(encoding: str) -> bytes:
    from l2e_studio.io.event_prophesee import encode_evt2, encode_evt3

    encode = encode_evt2 if encoding == "evt2" else encode_evt3
    return encode(EV["x"], EV["y"], EV["t"], EV["p"], W, H)


def _dat() -> bytes:
    from l2e_studio.io.event_prophesee import encode_dat

    return encode_dat(EV["x"], EV["y"], EV["t"], EV["p"], W, H)


def _h5(tmp: Path, layout: str) -> bytes:
    import h5py

    path = tmp / f"valid_{layout}.h5"
    with h5py.File(path, "w") as f:
        if layout == "groups":
            g = f.create_group("events")
            for k in ("x", "y", "t", "p"):
                g.create_dataset(k, data=EV[k][:100])
            f.create_dataset("t_offset", data=1000)
            g.attrs["width"], g.attrs["height"] = W, H
        else:
            rec = np.zeros(100, [("x", "<u2"), ("y", "<u2"), ("p", "<i2"), ("t", "<i8")])
            for k in ("x", "y", "t", "p"):
                rec[k] = EV[k][:100]
            f.create_dataset("CD/events", data=rec)
    return path.read_bytes()


def _event_text() -> bytes:
    return f"{W} {H}\n".encode() + "".join(f"{t / 1e6:.6f} {x} {y} {p}\n" for x, y, t, p in
                                           zip(EV["x"][:80], EV["y"][:80], EV["t"][:80], EV["p"][:80])).encode()


def _png_map() -> bytes:
    import cv2

    img = np.zeros((H, W), np.uint8)
    img[5:20, 10:30] = RNG.integers(1, 120, (15, 20))
    return cv2.imencode(".png", img)[1].tobytes()


def _tiff_map() -> bytes:
    import cv2

    img = (RNG.random((H, W)) * 90).astype(np.float32)
    return cv2.imencode(".tiff", img)[1].tobytes()


K = [[50.0, 0, 24.0], [0, 50.0, 16.0], [0, 0, 1]]
SEED = {"translation": [0.1, 0.0, 0.0], "rotvec": [1.2, -1.2, 1.2]}


def _rig_ours() -> bytes:
    return yaml.safe_dump({"camera": {"model": "radtan", "width": W, "height": H, "K": K, "D": [0.1, 0, 0, 0, 0]},
                           "seed": SEED}).encode()


def _rig_reference() -> bytes:
    return json.dumps({"cam": {"K": K, "D": [0.1, 0, 0, 0, 0], "x": 0.1, "y": 0, "z": 0,
                               "Rodrigues": [1.2, -1.2, 1.2]}}).encode()


def _rig_kalibr() -> bytes:
    return yaml.safe_dump({"cam0": {"camera_model": "pinhole", "intrinsics": [50.0, 50.0, 24.0, 16.0],
                                    "distortion_model": "radtan", "distortion_coeffs": [0.1, 0, 0, 0],
                                    "resolution": [W, H]}}).encode()


def _rig_opencv() -> bytes:
    return (f"%YAML:1.0\n---\nimage_width: {W}\nimage_height: {H}\ncamera_matrix: !!opencv-matrix\n   rows: 3\n"
            "   cols: 3\n   dt: d\n   data: [ 50., 0., 24., 0., 50., 16., 0., 0., 1. ]\n"
            "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"
            "   data: [ 0.1, 0., 0., 0., 0. ]\n").encode()


def _seed_matrix() -> bytes:
    from l2e_studio.geometry import Extrinsic

    T = Extrinsic(np.array(SEED["rotvec"]), np.array(SEED["translation"])).matrix
    return "".join(" ".join(f"{v:.9f}" for v in row) + "\n" for row in T).encode()


KITTI_CALIB = (b"P0: 707 0 601.9 0 0 707 183.1 0 0 0 1 0\n"
               b"P2: 707 0 601.9 42.4 0 707 183.1 1.4 0 0 1 0.003\n"
               b"Tr: 0 -1 0 -0.004 0 0 -1 -0.076 1 0 0 -0.27\n")
STATIC_TF = b"rosrun tf2_ros static_transform_publisher 0.1 0 0 0.5 -0.5 0.5 0.5 camera lidar\n"
URDF = b'<joint name="cam_lidar" type="fixed">\n  <origin xyz="0.1 0 0" rpy="1.5708 0 1.5708"/>\n' \
       b'  <parent link="camera"/>\n  <child link="lidar"/>\n</joint>\n'


def _bag(tmp: Path, ros2: bool, storage: str = "sqlite3") -> tuple[bytes, Callable[[Path], object]]:
    """A small bag (events, clouds, camera info) as the bytes of its one data file, and a loader
    that puts damaged bytes back in place of that file and extracts the bag."""
    import shutil

    from l2e_studio.io.bags import extract_bag

    folder = tmp / f"bag_{int(ros2)}_{storage}"
    if not ros2:
        write_bag(folder.with_suffix(".bag"), ros2=False)
        return folder.with_suffix(".bag").read_bytes(), lambda p: extract_bag(p, p.parent / "out")
    write_bag(folder, ros2=True, storage=storage)
    data_file = next(f for f in folder.iterdir() if f.name != "metadata.yaml")

    def load(path: Path):
        bag = path.parent / "bag2"
        shutil.rmtree(bag, ignore_errors=True)
        bag.mkdir()
        shutil.copy(folder / "metadata.yaml", bag)
        shutil.copy(path, bag / data_file.name)
        return extract_bag(bag, path.parent / "out")
    return data_file.read_bytes(), load


def check_extracted(scenes) -> None:
    assert scenes and all(s.events > 0 and s.points > 0 for s in scenes)


def targets(tmp: Path) -> list[Target]:
    scan_lies = ()
    return [
        Target("lidar .txt", ".txt", _text_scan(), load_scan, check_scan, scan_lies),
        Target("lidar .pcd ascii", ".pcd", _pcd("ascii"), load_scan, check_scan,
               ((b"POINTS 40", b"POINTS 4000000000"), (b"COUNT 1 1 1 1", b"COUNT 9 1 1 1"), (b"SIZE 4 4", b"SIZE 8 4"))),
        Target("lidar .pcd binary", ".pcd", _pcd("binary"), load_scan, check_scan,
               ((b"POINTS 40", b"POINTS 4000000000"), (b"POINTS 40", b"POINTS -40"), (b"WIDTH 40", b"WIDTH -1"),
                (b"COUNT 1 1 1 1", b"COUNT 100000000 1 1 1"), (b"TYPE F F", b"TYPE U F"))),
        Target("lidar .pcd binary_compressed", ".pcd", _pcd("binary_compressed"), load_scan, check_scan,
               ((b"POINTS 40", b"POINTS 4000000000"), (b"POINTS 40", b"POINTS -40"), (b"POINTS 40", b"POINTS 41"),
                (b"SIZE 4 4 4 4", b"SIZE 8 8 8 8"))),
        Target("lidar .ply ascii", ".ply", _ply("ascii"), load_scan, check_scan,
               ((b"vertex 40", b"vertex 4000000000"), (b"vertex 40", b"vertex -3"), (b"float x", b"list x"))),
        Target("lidar .ply binary", ".ply", _ply("binary_little_endian"), load_scan, check_scan,
               ((b"vertex 40", b"vertex 4000000000"), (b"vertex 40", b"vertex -3"), (b"float x", b"double x"),
                (b"binary_little_endian", b"binary_big_endian"))),
        Target("lidar KITTI .bin", ".bin", PTS.astype("<f4").tobytes(), load_scan, check_scan),
        Target("lidar nuScenes .pcd.bin", ".pcd.bin", np.column_stack([PTS, np.zeros(N)]).astype("<f4").tobytes(),
               load_scan, check_scan),
        Target("lidar .npy", ".npy", _npy(PTS), load_scan, check_scan,
               ((b"(40, 4)", b"(40000000, 4)"), (b"(40, 4)", b"(-40, 4)"), (b"'<f4'", b"'|O'"))),
        Target("lidar .npz", ".npz", _npz(points=PTS[:, :3], intensity=PTS[:, 3]), load_scan, check_scan,
               ((b"(40, 3)", b"(40000000, 3)"),)),
        Target("lidar .npz compressed", ".npz", _npz(True, x=PTS[:, 0], y=PTS[:, 1], z=PTS[:, 2], intensity=PTS[:, 3]),
               load_scan, check_scan),
        Target("lidar .las", ".las", _las(".las"), load_scan, check_scan),
        Target("lidar .laz", ".laz", _las(".laz"), load_scan, check_scan),
        Target("events EVT 2.0 .raw", ".raw", _raw("evt2"), load_events, check_events,
               ((b"48x32", b"100000x100000"), (b"evt 2.0", b"evt 3.0"), (b"evt 2.0", b"evt 9.0"))),
        Target("events EVT 3.0 .raw", ".raw", _raw("evt3"), load_events, check_events,
               ((b"48x32", b"100000x100000"), (b"evt 3.0", b"evt 2.0"))),
        Target("events .dat", ".dat", _dat(), load_events, check_events,
               ((b"Height 32", b"Height 99999999"), (b"Width 48", b"Width -48"))),
        Target("events HDF5 groups", ".h5", _h5(tmp, "groups"), load_events, check_events),
        Target("events HDF5 table", ".h5", _h5(tmp, "table"), load_events, check_events),
        Target("events .npz", ".npz", _npz(**EV, sensor_size=np.array([W, H])), load_events, check_events,
               ((b"(300,)", b"(300000000,)"), (b"(2,)", b"(3,)"))),
        Target("events .npy", ".npy", _npy(np.column_stack([EV["t"], EV["x"], EV["y"], EV["p"]]).astype(np.float64)),
               load_events, check_events, ((b"(300, 4)", b"(300000000, 4)"), (b"(300, 4)", b"(300, 5)"))),
        Target("events .txt", ".txt", _event_text(), load_events, check_events, ((b"48 32", b"100000 100000"),)),
        Target("map .png", ".png", _png_map(), load_map_file, check_map),
        Target("map .tiff (float)", ".tiff", _tiff_map(), load_map_file, check_map),
        Target("map .npy", ".npy", _npy((RNG.random((H, W)) * 50).astype(np.float32)), load_map_file, check_map,
               ((b"(32, 48)", b"(32000, 48000)"),)),
        Target("camera ours .yaml", ".yaml", _rig_ours(), load_rig_file, check_rig,
               ((b"width: 48", b"width: 4800000000"), (b"width: 48", b"width: .nan"))),
        Target("camera reference .json", ".json", _rig_reference(), load_rig_file, check_rig),
        Target("camera Kalibr .yaml", ".yaml", _rig_kalibr(), load_rig_file, check_rig),
        Target("camera OpenCV .yaml", ".yaml", _rig_opencv(), load_rig_file, check_rig,
               ((b"rows: 3", b"rows: 300000"), (b"rows: 3", b"rows: -3"))),
        Target("camera KITTI calib.txt", ".txt", KITTI_CALIB, load_rig_file, check_rig,
               ((b"707 0 601.9 42.4", b"-707 0 601.9 42.4"), (b"Tr: 0 -1 0", b"Tr: 0 -1e30 0"))),
        Target("seed KITTI calib.txt", ".txt", KITTI_CALIB, load_seed_file, check_seed),
        Target("seed matrix .txt", ".txt", _seed_matrix(), load_seed_file, check_seed),
        Target("seed static_transform_publisher", ".txt", STATIC_TF, load_seed_file, check_seed,
               ((b"0.5 -0.5 0.5 0.5", b"0 0 0 0"), (b"0.5 -0.5 0.5 0.5", b"nan 0 0 1"))),
        Target("seed URDF joint", ".urdf", URDF, load_seed_file, check_seed, ((b'xyz="0.1 0 0"', b'xyz="0.1 0"'),)),
        Target("seed .npy", ".npy", _npy(np.eye(4)), load_seed_file, check_seed, ((b"(4, 4)", b"(4000, 4000)"),)),
        # bags are slow to open (a fresh typestore each): fewer cases
        Target("bag ROS 1", ".bag", *_bag(tmp, False), check_extracted, truncations=50, flips=40),
        Target("bag ROS 2 sqlite3", ".db3", *_bag(tmp, True), check_extracted, truncations=25, flips=20),
        Target("bag ROS 2 mcap", ".mcap", *_bag(tmp, True, "mcap"), check_extracted, truncations=25, flips=20),
    ]



@pytest.fixture(scope="module")
def all_targets(tmp_path_factory) -> dict[str, Target]:
    return {t.name: t for t in targets(tmp_path_factory.mktemp("valid"))}


def _names() -> list[str]:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        return [t.name for t in targets(Path(tmp))]


@pytest.mark.parametrize("name", _names())
def test_reader_survives_fuzz(name: str, all_targets, tmp_path: Path) -> None:
    report = run_target(all_targets[name], tmp_path)
    print(f"{name}: {report.cases} cases, {report.loaded} loaded, {report.refused} refused, "
          f"{report.seconds:.1f} s, peak {report.peak_mb:.0f} MB traced")
    assert not report.findings, f"{len(report.findings)} of {report.cases} cases failed:\n" + "\n".join(report.findings[:8])
    assert report.refused > 0  # the damage reached the reader


@pytest.mark.realdata
def test_aedat4_survives_fuzz(tmp_path: Path) -> None:
    """AEDAT4 has no writer here: the real sample (949 kB) is damaged instead, fewer cases."""
    sample = REALDATA / "event_camera_samples" / "sample.aedat4"
    if not sample.is_file():
        pytest.skip(f"{sample} is absent")
    target = Target("events .aedat4", ".aedat4", sample.read_bytes(), load_events, check_events, truncations=40, flips=40)
    report = run_target(target, tmp_path)
    print(f"{target.name}: {report.cases} cases, {report.loaded} loaded, {report.refused} refused, {report.seconds:.1f} s")
    assert not report.findings, "\n".join(report.findings[:8])
