"""Damaged values that once slipped past the readers as NumPy warnings (seen on a fresh Debian run of
the suite): a reader either uses a value or refuses it in one line, with no warning beside it."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from l2e_studio.errors import InputError
from l2e_studio.io.cameras import load_seed
from l2e_studio.io.lidar import load_lidar


def _pcd_scan(path: Path, ring: np.ndarray) -> Path:
    n = len(ring)
    xyz = np.random.default_rng(3).uniform(-20, 20, (n, 3))
    header = (f"VERSION 0.7\nFIELDS x y z intensity ring\nSIZE 4 4 4 4 4\nTYPE F F F F F\nCOUNT 1 1 1 1 1\n"
              f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA ascii\n")
    rows = [f"{x:.3f} {y:.3f} {z:.3f} {i} {float(r)!r}" for (x, y, z), i, r in zip(xyz, range(n), ring)]
    path.write_text(header + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("bad", [1e30, -3.0, 2.5e9, float("nan"), float("inf")])
def test_a_ring_field_out_of_any_lidars_range_is_not_used_and_warns_nothing(tmp_path: Path, bad: float) -> None:
    ring = np.arange(40, dtype=np.float64) % 16
    good = load_lidar(_pcd_scan(tmp_path / "good.pcd", ring))
    assert good.ring is not None and good.ring.max() == 15
    ring[7] = bad
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an overflowing cast would raise here
        scan = load_lidar(_pcd_scan(tmp_path / "bad.pcd", ring))
    assert scan.ring is None and len(scan) == 40


def test_a_seed_with_huge_rotation_entries_is_refused_without_overflow(tmp_path: Path) -> None:
    path = tmp_path / "seed.txt"
    path.write_text("1e200 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError) as exc:
            load_seed(path)
    line = str(exc.value)
    assert "\n" not in line and str(path) in line and "not a rotation" in line
