"""``l2e-studio accumulate``: raw files in events_raw/ become event/<stem>.png; in-place raw files get cached."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from l2e_studio.cli import main
from l2e_studio.io import event_prophesee as pr
from l2e_studio.io.events import accumulate_events, cache_paths


def _events(seed: int, n: int = 5000):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 4_000_000, n))
    return rng.integers(0, 64, n), rng.integers(0, 32, n), t, rng.integers(0, 2, n)


def test_accumulate_folder(tmp_path: Path, capsys, monkeypatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    (tmp_path / "events_raw").mkdir()
    (tmp_path / "event").mkdir()
    (tmp_path / "events_raw" / "s1.raw").write_bytes(pr.encode_evt3(*_events(1), 64, 32))
    (tmp_path / "events_raw" / "s2.dat").write_bytes(pr.encode_dat(*_events(2), 64, 32))
    (tmp_path / "event" / "s3.raw").write_bytes(pr.encode_evt2(*_events(3), 64, 32))
    assert main(["accumulate", str(tmp_path), "--window", "2", "--start", "0.5"]) == 0
    for stem, name in (("s1", "s1.raw"), ("s2", "s2.dat")):
        png = cv2.imread(str(tmp_path / "event" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
        want = accumulate_events(tmp_path / "events_raw" / name, window_s=2, start_s=0.5)
        assert png.dtype == np.uint8 and png.shape == (32, 64)
        np.testing.assert_array_equal(png, want)
    assert not (tmp_path / "event" / "s3.png").exists()
    assert cache_paths(tmp_path / "event" / "s3.raw")[0].is_file()
    assert "2 map(s) written" in capsys.readouterr().out
    # Existing PNGs are kept without --force.
    before = (tmp_path / "event" / "s1.png").read_bytes()
    assert main(["accumulate", str(tmp_path), "--window", "0.1"]) == 0
    assert (tmp_path / "event" / "s1.png").read_bytes() == before
    assert main(["accumulate", str(tmp_path), "--window", "0.1", "--force"]) == 0
    assert (tmp_path / "event" / "s1.png").read_bytes() != before


def test_accumulate_errors(tmp_path: Path, capsys) -> None:
    assert main(["accumulate", str(tmp_path / "nope")]) == 2
    assert "scene folder not found" in capsys.readouterr().err
    assert main(["accumulate", str(tmp_path)]) == 2
    assert "no raw event files" in capsys.readouterr().err
