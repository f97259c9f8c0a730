"""LAS/LAZ lidar files through laspy: values, intensity scaling, and bad files as one line."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from l2e_studio.errors import InputError
from l2e_studio.io.lidar import load_lidar, scale_intensity

laspy = pytest.importorskip("laspy")
RNG = np.random.default_rng(0)
POINTS = RNG.uniform(-20, 20, (5000, 3))
INTENSITY = RNG.integers(1, 65535, 5000).astype(np.uint16)


def _write(path: Path, intensity: bool = True) -> Path:
    header = laspy.LasHeader(point_format=1 if intensity else 0, version="1.2")
    header.scales, header.offsets = [0.001] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = POINTS.T
    if intensity:
        las.intensity = INTENSITY
    las.write(path)
    return path


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_and_laz_round_trip(tmp_path: Path, suffix: str) -> None:
    scan = load_lidar(_write(tmp_path / f"a{suffix}"))
    assert len(scan) == len(POINTS) and scan.has_intensity and scan.intensity_field == "intensity"
    np.testing.assert_allclose(scan.points, POINTS, atol=1e-3)
    np.testing.assert_allclose(scan.intensity, scale_intensity(INTENSITY.astype(np.float64)), rtol=1e-6)


def test_laz_is_smaller_than_las(tmp_path: Path) -> None:
    assert (_write(tmp_path / "a.laz").stat().st_size < 0.5 * _write(tmp_path / "a.las").stat().st_size)


def test_a_header_declaring_more_points_than_the_file_holds_is_refused(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.las")
    data = bytearray(path.read_bytes())
    data[107:111] = struct.pack("<I", 2**31)  # LAS 1.2 legacy point count
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="a.las: the header declares 2147483648 points"):
        load_lidar(path)


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_garbage_is_one_input_error(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"a{suffix}"
    path.write_bytes(RNG.bytes(3000))
    with pytest.raises(InputError, match=f"a{suffix}: "):
        load_lidar(path)
