"""Decoding checks on real recordings (../shared/realdata/event_camera_samples), against SOURCE.md."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from l2e_studio.errors import InputError
from l2e_studio.io.events import accumulate_events, event_stats, iter_events, sensor_size

pytestmark = pytest.mark.realdata

SAMPLES = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "event_camera_samples"


def _file(name: str) -> Path:
    path = SAMPLES / name
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    return path


# name, events, (width, height) from the header (None: the file does not say), max x, max y, duration (s)
CASES = [
    ("evt3_sample.raw", 219596, (1280, 720), 1279, 719),
    ("evt2.raw", 521252, (640, 480), 639, 479),
    ("sample.aedat4", 111954, (320, 240), 319, 239),
    ("sample_ncars.dat", 2009, None, 77, 41),
]


@pytest.mark.parametrize("name, count, size, x_max, y_max", CASES)
def test_counts_ranges_and_size_match_source(name: str, count: int, size, x_max: int, y_max: int) -> None:
    path = _file(name)
    stats = event_stats(path, chunk_size=50_000)  # several chunks: state carried across them
    assert stats.count == count
    assert (stats.x_min, stats.y_min) == (0, 0)
    assert (stats.x_max, stats.y_max) == (x_max, y_max)
    assert sensor_size(path) == size
    assert 0 < stats.on < stats.count  # both polarities present
    assert stats.t_last_us > stats.t_first_us


def test_durations() -> None:
    # SOURCE.md: evt2 96 ms, aedat4 0.59 s, dat 100 ms. For the EVT3 sample it says 54 ms, but its
    # TIME_HIGH words only run from 2861 to 2863 (x 4096 us), so the stream spans under 12.3 ms.
    assert event_stats(_file("evt2.raw")).duration_s == pytest.approx(0.096, abs=0.002)
    assert event_stats(_file("sample.aedat4")).duration_s == pytest.approx(0.59, abs=0.01)
    assert event_stats(_file("sample_ncars.dat")).duration_s == pytest.approx(0.1, abs=0.002)
    assert 0.005 < event_stats(_file("evt3_sample.raw")).duration_s < 3 * 4096e-6


def test_time_is_monotonic_in_prophesee_raw() -> None:
    for name in ("evt2.raw", "evt3_sample.raw"):
        t = np.concatenate([c.t_us for c in iter_events(_file(name), chunk_size=10_007)])
        assert np.all(np.diff(t) >= 0), name


def test_accumulated_map_has_structure() -> None:
    path = _file("evt3_sample.raw")
    m = accumulate_events(path)  # 3 s window covers the whole 9 ms sample
    assert m.shape == (720, 1280) and m.max() <= 127
    total = accumulate_events(path, clip=None).sum()
    assert total == 219596
    # A street scene with edges: events concentrate on a minority of pixels.
    assert 0.02 < np.count_nonzero(m) / m.size < 0.5


def test_truncated_aedat4_is_a_clean_error_or_a_prefix(tmp_path: Path) -> None:
    data = _file("sample.aedat4").read_bytes()
    cut = tmp_path / "cut.aedat4"
    cut.write_bytes(data[: len(data) // 2])
    try:
        n = sum(len(c) for c in iter_events(cut))
    except InputError as exc:
        assert str(cut) in str(exc)
    else:
        assert 0 < n < 111954
