"""HDF5 event files compressed with blosc/zstd: read with the [hdf5] extra, one clear line without it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

hdf5plugin = pytest.importorskip("hdf5plugin")


@pytest.fixture
def blosc_h5(tmp_path: Path) -> Path:
    import h5py

    rng = np.random.default_rng(0)
    n = 1000
    with h5py.File(tmp_path / "a.h5", "w") as f:
        g = f.create_group("events")
        for k, v in dict(x=rng.integers(0, 100, n).astype("u2"), y=rng.integers(0, 50, n).astype("u2"),
                         t=np.sort(rng.integers(0, 10**6, n)), p=rng.integers(0, 2, n).astype("u1")).items():
            g.create_dataset(k, data=v, **hdf5plugin.Blosc(cname="zstd"))
    return tmp_path / "a.h5"


_READ = "from l2e_studio.io.events import accumulate_events; print(accumulate_events({!r}, window_s=10).sum())"


def test_blosc_zstd_events_read_with_hdf5plugin(blosc_h5: Path) -> None:
    proc = subprocess.run([sys.executable, "-c", _READ.format(str(blosc_h5))], capture_output=True, text=True)
    assert proc.returncode == 0 and float(proc.stdout) == 1000.0, proc.stderr


def test_without_hdf5plugin_the_error_says_what_to_install(blosc_h5: Path) -> None:
    code = "import sys; sys.modules['hdf5plugin'] = None\n" + _READ.format(str(blosc_h5))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode != 0
    assert "a.h5: compressed with an HDF5 filter" in proc.stderr and "l2e-studio[hdf5]" in proc.stderr
    assert "ECF" in proc.stderr
