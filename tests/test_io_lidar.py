"""Lidar readers: every format round-trips points and intensities; bad files raise InputError."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from l2e_studio.errors import InputError
from l2e_studio.io import _lzf
from l2e_studio.io.lidar import LIDAR_SUFFIXES, lidar_suffix, load_lidar, scale_intensity, write_lidar_txt


@pytest.fixture()
def cloud() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    pts = rng.uniform(-20, 20, size=(500, 3)).astype(np.float32)
    inten = rng.integers(0, 256, size=500).astype(np.float32)
    return pts, inten


def test_txt_round_trip(tmp_path: Path, cloud) -> None:
    pts, inten = cloud
    path = write_lidar_txt(tmp_path / "a.txt", pts, inten)
    scan = load_lidar(path)
    np.testing.assert_allclose(scan.points, pts, atol=1e-5)
    np.testing.assert_allclose(scan.intensity, inten, atol=1e-3)
    assert scan.points.dtype == np.float32 and scan.intensity.dtype == np.float32


def test_txt_whitespace_header_and_bad_rows_dropped(tmp_path: Path) -> None:
    text = "x y z reflectivity intensity\n1 2 3 0.5 10\nnan 1 1 0.1 20\n0 0 0 0.2 30\n\n4 5 6 1.0 40\n"
    path = tmp_path / "b.csv"
    path.write_text(text)
    scan = load_lidar(path)  # default picks "intensity"
    np.testing.assert_allclose(scan.points, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_allclose(scan.intensity, [10, 40])
    refl = load_lidar(path, intensity_field="reflectivity")  # [0, 1] range -> * 255
    np.testing.assert_allclose(refl.intensity, [127.5, 255.0])
    with pytest.raises(InputError, match="no intensity field 'ambient'"):
        load_lidar(path, intensity_field="ambient")


def test_intensity_scaling_rules() -> None:
    np.testing.assert_allclose(scale_intensity(np.array([0.0, 0.5, 1.0])), [0, 127.5, 255])
    np.testing.assert_allclose(scale_intensity(np.array([0.0, 17.0, 200.0])), [0, 17, 200])
    wide = np.concatenate([np.linspace(0, 4000, 1000), [65535.0]])
    out = scale_intensity(wide)
    assert out.max() == 255.0 and out.min() == 0.0
    assert out[500] > 100  # the bulk is spread over the range, not squashed by one bright return
    np.testing.assert_allclose(scale_intensity(np.array([-10.0, 0.0, 10.0])), [0, 10, 20])


@pytest.mark.parametrize("encoding", ["ascii", "binary", "binary_compressed"])
def test_pcd_written_by_open3d(tmp_path: Path, cloud, encoding: str) -> None:
    o3d = pytest.importorskip("open3d")
    pts, inten = cloud
    pc = o3d.t.geometry.PointCloud()
    pc.point.positions = o3d.core.Tensor(pts)
    pc.point.intensity = o3d.core.Tensor(inten.reshape(-1, 1))
    path = tmp_path / f"{encoding}.pcd"
    o3d.t.io.write_point_cloud(str(path), pc, write_ascii=encoding == "ascii", compressed=encoding == "binary_compressed")
    assert f"DATA {encoding}" in path.read_bytes()[:400].decode("ascii", "replace")
    scan = load_lidar(path)
    np.testing.assert_allclose(scan.points, pts, atol=1e-4)
    np.testing.assert_allclose(scan.intensity, inten, atol=1e-3)
    assert scan.intensity_field == "intensity"


def _pcd_header(fields, sizes, types, n, data) -> bytes:
    return (f"# .PCD v0.7\nVERSION 0.7\nFIELDS {' '.join(fields)}\nSIZE {' '.join(map(str, sizes))}\n"
            f"TYPE {' '.join(types)}\nCOUNT {' '.join('1' for _ in fields)}\nWIDTH {n}\nHEIGHT 1\n"
            f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n").encode()


def test_pcd_hand_built_binary_and_compressed_with_mixed_types(tmp_path: Path, cloud) -> None:
    pts, inten = cloud
    n = len(pts)
    ring = (np.arange(n) % 64).astype(np.uint16)
    stamp = np.linspace(0, 0.1, n)
    refl = (inten * 100).astype(np.uint16)  # a 16-bit field to choose explicitly
    fields = ["x", "y", "z", "intensity", "ring", "timestamp", "reflectivity"]
    header_args = (fields, [4, 4, 4, 4, 2, 8, 2], ["F", "F", "F", "F", "U", "F", "U"], n)
    rec = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("i", "<f4"), ("r", "<u2"), ("t", "<f8"), ("q", "<u2")])
    rec["x"], rec["y"], rec["z"], rec["i"], rec["r"], rec["t"], rec["q"] = *pts.T, inten, ring, stamp, refl
    (tmp_path / "bin.pcd").write_bytes(_pcd_header(*header_args, "binary") + rec.tobytes())
    columns = b"".join(np.ascontiguousarray(rec[name]).tobytes() for name in rec.dtype.names)
    packed = _lzf.compress(columns)
    (tmp_path / "cmp.pcd").write_bytes(_pcd_header(*header_args, "binary_compressed")
                                       + struct.pack("<II", len(packed), len(columns)) + packed)
    for name in ("bin.pcd", "cmp.pcd"):
        scan = load_lidar(tmp_path / name)
        np.testing.assert_allclose(scan.points, pts)
        np.testing.assert_allclose(scan.intensity, inten)
        wide = load_lidar(tmp_path / name, intensity_field="reflectivity")
        assert wide.intensity.max() == 255.0
        assert np.corrcoef(wide.intensity, inten)[0, 1] > 0.99


def test_lzf_back_references_round_trip() -> None:
    # A hand-made stream: literal "abc", then a back-reference copying 6 bytes from distance 3.
    stream = bytes([2]) + b"abc" + bytes([(4 << 5) | 0, 2])
    assert _lzf._decompress_py(stream, 9) == b"abcabcabc"
    with pytest.raises(ValueError):
        _lzf._decompress_py(stream, 12)


def test_ply_ascii_and_binary_via_open3d(tmp_path: Path, cloud) -> None:
    o3d = pytest.importorskip("open3d")
    pts, inten = cloud
    pc = o3d.t.geometry.PointCloud()
    pc.point.positions = o3d.core.Tensor(pts)
    pc.point.intensity = o3d.core.Tensor(inten.reshape(-1, 1))
    for ascii_ in (True, False):
        path = tmp_path / f"c{int(ascii_)}.ply"
        o3d.t.io.write_point_cloud(str(path), pc, write_ascii=ascii_)
        scan = load_lidar(path)
        np.testing.assert_allclose(scan.points, pts, atol=1e-4)
        np.testing.assert_allclose(scan.intensity, inten, atol=1e-3)


def test_ply_big_endian_hand_built(tmp_path: Path, cloud) -> None:
    pts, inten = cloud
    rec = np.zeros(len(pts), dtype=[("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("intensity", ">u1")])
    rec["x"], rec["y"], rec["z"] = pts.T
    rec["intensity"] = inten.astype(np.uint8)
    header = (f"ply\nformat binary_big_endian 1.0\nelement vertex {len(pts)}\nproperty float x\nproperty float y\n"
              "property float z\nproperty uchar intensity\nend_header\n").encode()
    (tmp_path / "be.ply").write_bytes(header + rec.tobytes())
    scan = load_lidar(tmp_path / "be.ply")
    np.testing.assert_allclose(scan.points, pts)
    np.testing.assert_allclose(scan.intensity, inten)


def test_kitti_and_nuscenes_bin(tmp_path: Path, cloud) -> None:
    pts, inten = cloud
    refl = inten / 255.0  # KITTI reflectance is in [0, 1]
    np.column_stack([pts, refl]).astype("<f4").tofile(tmp_path / "000001.bin")
    scan = load_lidar(tmp_path / "000001.bin")
    np.testing.assert_allclose(scan.points, pts)
    np.testing.assert_allclose(scan.intensity, inten, atol=1e-3)
    np.column_stack([pts, inten, np.arange(len(pts)) % 32]).astype("<f4").tofile(tmp_path / "sweep.pcd.bin")
    assert lidar_suffix(tmp_path / "sweep.pcd.bin") == ".pcd.bin"
    scan = load_lidar(tmp_path / "sweep.pcd.bin")
    np.testing.assert_allclose(scan.intensity, inten)
    (tmp_path / "bad.bin").write_bytes(b"\0" * 30)
    with pytest.raises(InputError, match="not a multiple of 16 bytes"):
        load_lidar(tmp_path / "bad.bin")


def test_npy_and_npz(tmp_path: Path, cloud) -> None:
    pts, inten = cloud
    np.save(tmp_path / "a.npy", np.column_stack([pts, inten]))
    rec = np.zeros(len(pts), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("intensity", "f4")])
    rec["x"], rec["y"], rec["z"], rec["intensity"] = *pts.T, inten
    np.save(tmp_path / "b.npy", rec)
    np.savez(tmp_path / "c.npz", points=pts, intensity=inten)
    np.savez(tmp_path / "d.npz", x=pts[:, 0], y=pts[:, 1], z=pts[:, 2], intensity=inten)
    for name in ("a.npy", "b.npy", "c.npz", "d.npz"):
        scan = load_lidar(tmp_path / name)
        np.testing.assert_allclose(scan.points, pts, err_msg=name)
        np.testing.assert_allclose(scan.intensity, inten, err_msg=name)
    np.save(tmp_path / "e.npy", pts[:, :2])
    with pytest.raises(InputError, match="at least 3 columns"):
        load_lidar(tmp_path / "e.npy")


def test_no_intensity_field_is_flagged(tmp_path: Path, cloud) -> None:
    pts, _ = cloud
    np.save(tmp_path / "xyz.npy", pts)
    scan = load_lidar(tmp_path / "xyz.npy")
    assert not scan.has_intensity and np.all(scan.intensity == 0)


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("missing.txt", None, "not found"),
        ("empty.txt", b"", "empty"),
        ("cols.txt", b"1,2\n3,4\n", "3 or more columns"),
        ("ragged.txt", b"1,2,3,4\n5,6,7\n", "line 2 has 3 columns"),
        ("words.txt", b"1,2,3,4\n5,six,7,8\n", "not numeric"),
        ("allnan.txt", b"nan,1,1,1\n0,0,0,5\n", "none of the 2 points is valid"),
        ("scan.las", b"LASF", "cannot read the LAS/LAZ file"),
        ("scan.e57", b"ASTM-E57", "unknown lidar format"),
        ("noheader.pcd", b"garbage\x00\x01", "PCD"),
        ("trunc.pcd", _pcd_header(["x", "y", "z"], [4, 4, 4], ["F", "F", "F"], 10, "binary") + b"\0" * 20, "truncated"),
        ("enc.pcd", _pcd_header(["x", "y", "z"], [4, 4, 4], ["F", "F", "F"], 1, "lz4") + b"\0" * 12, "unknown PCD DATA"),
        ("corrupt.pcd", _pcd_header(["x", "y", "z"], [4, 4, 4], ["F", "F", "F"], 1, "binary_compressed")
         + struct.pack("<II", 4, 12) + b"\xff\xff\xff\xff", "LZF"),
        ("bad.ply", b"plyx\nformat ascii 1.0\n", "end_header"),
        ("trunc.npy", b"\x93NUMPY\x01\x00", "cannot read"),
    ],
)
def test_bad_input_raises_input_error(tmp_path: Path, name: str, content: bytes | None, message: str) -> None:
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError, match=message) as info:
        load_lidar(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_suffix_list_is_accurate(tmp_path: Path, cloud) -> None:
    assert lidar_suffix("a/b/c.PCD") == ".pcd"
    assert set(LIDAR_SUFFIXES) >= {".txt", ".csv", ".pcd", ".ply", ".bin", ".pcd.bin", ".npy", ".npz"}
