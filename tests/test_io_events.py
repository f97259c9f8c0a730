"""Raw event decoding and accumulation: round trips for every format, chunking, caching, bad input."""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np
import pytest

from l2e_studio.errors import InputError
from l2e_studio.io import event_prophesee as pr
from l2e_studio.io.events import (
    EVENT_SUFFIXES, accumulate_events, accumulate_events_cached, cache_paths, event_stats, iter_events,
    sensor_size, suppress_hot_pixels,
)
from l2e_studio.io.maps import load_map

W, H = 320, 240


@pytest.fixture(scope="module")
def events() -> tuple[np.ndarray, ...]:
    """Time-sorted events over 20 s (past one 16.7 s EVT3 time wrap), with vector-friendly runs."""
    rng = np.random.default_rng(7)
    n_runs = 3000
    t = np.sort(rng.integers(0, 20_000_000, n_runs))
    xs, ys, ts, ps = [], [], [], []
    for i in range(n_runs):
        run = np.unique(rng.integers(0, W - 30) + rng.integers(0, 24, rng.integers(1, 12)))
        xs.append(run)
        ys.append(np.full(run.size, rng.integers(0, H)))
        ts.append(np.full(run.size, t[i]))
        ps.append(np.full(run.size, rng.integers(0, 2)))
    return tuple(np.concatenate(a) for a in (xs, ys, ts, ps))


def _collect(path: Path, chunk: int = 1000) -> tuple[np.ndarray, ...]:
    chunks = list(iter_events(path, chunk_size=chunk))
    return tuple(np.concatenate([getattr(c, k) for c in chunks]) for k in ("x", "y", "t_us", "p"))


def _assert_same(got, want) -> None:
    for g, w_, name in zip(got, want, "x y t p".split()):
        np.testing.assert_array_equal(g.astype(np.int64), w_.astype(np.int64), err_msg=name)


@pytest.mark.parametrize("fmt", ["evt2", "evt3", "evt3-single", "dat"])
@pytest.mark.parametrize("chunk", [5, 997, 10_000_000])
def test_prophesee_round_trip_any_chunking(tmp_path: Path, events, fmt: str, chunk: int) -> None:
    x, y, t, p = events
    if fmt == "dat":
        data, name = pr.encode_dat(x, y, t, p, W, H), "a.dat"
    elif fmt == "evt2":
        data, name = pr.encode_evt2(x, y, t, p, W, H), "a.raw"
    else:
        data, name = pr.encode_evt3(x, y, t, p, W, H, vectorize=fmt == "evt3"), "a.raw"
    (tmp_path / name).write_bytes(data)
    _assert_same(_collect(tmp_path / name, chunk), events)
    assert sensor_size(tmp_path / name) == (W, H)


def test_evt3_encoder_really_uses_vectors(events) -> None:
    data = pr.encode_evt3(*events, W, H)
    words = np.frombuffer(data[data.index(b"% end\n") + 6:], "<u2")
    kinds = np.bincount(words >> 12, minlength=16)
    assert kinds[0x3] > 0 and kinds[0x4] > 0 and kinds[0x5] > 0 and kinds[0x2] > 0


def test_hdf5_dsec_layout_with_t_offset(tmp_path: Path, events) -> None:
    x, y, t, p = events
    path = tmp_path / "events.h5"
    with h5py.File(path, "w") as f:
        g = f.create_group("events")
        g.create_dataset("x", data=x.astype(np.uint16))
        g.create_dataset("y", data=y.astype(np.uint16))
        g.create_dataset("t", data=(t - 1000).astype(np.uint32))
        g.create_dataset("p", data=p.astype(np.uint8))
        f.create_dataset("t_offset", data=np.int64(1000))
        f.create_dataset("ms_to_idx", data=np.searchsorted(t, np.arange(0, 20_000, 1) * 1000))
    _assert_same(_collect(path), events)


def test_hdf5_compound_table_and_size_attrs(tmp_path: Path, events) -> None:
    x, y, t, p = events
    rec = np.zeros(t.size, dtype=[("x", "<u2"), ("y", "<u2"), ("p", "<i2"), ("t", "<i8")])
    rec["x"], rec["y"], rec["p"], rec["t"] = x, y, np.where(p > 0, 1, -1), t
    path = tmp_path / "cd.hdf5"
    with h5py.File(path, "w") as f:
        f.create_group("CD").create_dataset("events", data=rec)
        f.attrs["width"], f.attrs["height"] = W, H
    _assert_same(_collect(path), events)
    assert sensor_size(path) == (W, H)


def test_numpy_and_text_layouts(tmp_path: Path, events) -> None:
    x, y, t, p = events
    np.savez(tmp_path / "a.npz", x=x, y=y, t=t, p=p)
    np.savez(tmp_path / "b.npz", x=x, y=y, timestamp=t * 1e-6, polarity=p)  # float seconds
    rec = np.zeros(t.size, dtype=[("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
    rec["t"], rec["x"], rec["y"], rec["p"] = t, x, y, p
    np.save(tmp_path / "c.npy", rec)
    np.save(tmp_path / "d.npy", np.column_stack([t, x, y, p]).astype(np.int64))
    with open(tmp_path / "e.txt", "w") as f:  # Event Camera Dataset style: seconds, with a size line
        f.write(f"{W} {H}\n")
        np.savetxt(f, np.column_stack([t * 1e-6, x, y, p]), fmt=["%.6f", "%d", "%d", "%d"])
    np.savetxt(tmp_path / "f.txt", np.column_stack([t, x, y, p]), fmt="%d")  # integer microseconds
    for name in ("a.npz", "b.npz", "c.npy", "d.npy", "e.txt", "f.txt"):
        _assert_same(_collect(tmp_path / name, chunk=4000), events)
    assert sensor_size(tmp_path / "e.txt") == (W, H)


def test_accumulate_window_counts_every_polarity(tmp_path: Path) -> None:
    # 5 events at pixel (3, 2) inside [1 s, 2 s), 2 outside; 200 events at (10, 5): clipped to 127.
    t = np.array([0, 1_000_000, 1_200_000, 1_500_000, 1_700_000, 1_999_999, 2_000_000] + [1_100_000] * 200)
    x = np.array([3] * 7 + [10] * 200)
    y = np.array([2] * 7 + [5] * 200)
    p = np.array([0, 1, 0, 1, 0, 1, 0] + [1] * 200)
    o = np.argsort(t, kind="stable")
    path = tmp_path / "w.raw"
    path.write_bytes(pr.encode_evt3(x[o], y[o], t[o], p[o], 16, 8))
    m = accumulate_events(path, window_s=1.0, start_s=1.0)
    assert m.shape == (8, 16) and m.dtype == np.float32
    assert m[2, 3] == 5 and m[5, 10] == 127 and m.sum() == 5 + 127
    raw = accumulate_events(path, window_s=10.0, clip=None)
    assert raw[2, 3] == 7 and raw[5, 10] == 200
    with pytest.raises(InputError, match="no events in the window"):
        accumulate_events(path, window_s=1.0, start_s=50.0)


def test_unknown_size_grows_and_a_too_small_size_is_refused(tmp_path: Path, events) -> None:
    """Events outside an explicit size are counted: a crop of most of them is an error, not a map."""
    x, y, t, p = events
    np.savez(tmp_path / "a.npz", x=x, y=y, t=t, p=p)
    grown = accumulate_events(tmp_path / "a.npz", window_s=100, clip=None, chunk_size=500)
    assert grown.shape == (y.max() + 1, x.max() + 1) and grown.sum() == t.size
    outside = np.count_nonzero((x >= 100) | (y >= 50))
    with pytest.raises(InputError, match=f"{outside} of {t.size} events in the window fall outside the 100x50 sensor"):
        accumulate_events(tmp_path / "a.npz", window_s=100, clip=None, width=100, height=50)


def test_hot_pixels_are_zeroed() -> None:
    rng = np.random.default_rng(0)
    counts = rng.poisson(5, size=(40, 60)).astype(float)
    counts[10, 10] = 5000
    out = suppress_hot_pixels(counts, 6.0)
    assert out[10, 10] == 0 and np.count_nonzero(out != counts) <= 3


def test_cache_used_and_invalidated(tmp_path: Path, events, monkeypatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    x, y, t, p = events
    path = tmp_path / "event" / "s1.raw"
    path.parent.mkdir()
    path.write_bytes(pr.encode_evt3(x, y, t, p, W, H))
    first, kind = load_map(path, width=W, height=H)
    assert kind == "events" and first.shape == (H, W)
    cache = cache_paths(path)[0]
    assert cache.is_file()
    # Same key -> served from the cache (prove it by planting a different map under that key).
    with np.load(cache) as z:
        key = str(z["key"])
    np.savez_compressed(cache, key=np.array(key), map=np.full((H, W), 7, np.float32))
    assert np.all(accumulate_events_cached(path, width=W, height=H) == 7)
    # Another window -> another key -> recomputed.
    other = accumulate_events_cached(path, window_s=1.0, width=W, height=H)
    assert other.sum() < first.sum() or np.all(first == 127)
    # Touching the file invalidates.
    os.utime(path, ns=(path.stat().st_atime_ns, path.stat().st_mtime_ns + 10**9))
    np.testing.assert_array_equal(accumulate_events_cached(path, width=W, height=H), first)


def test_map_cache_goes_to_the_user_cache_dir_never_beside_the_data(tmp_path: Path, events, monkeypatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    x, y, t, p = events
    path = tmp_path / "data" / "s.dat"
    path.parent.mkdir()
    path.write_bytes(pr.encode_dat(x, y, t, p, W, H))
    user, beside = cache_paths(path)
    first = accumulate_events_cached(path)
    assert user.is_file() and str(user).startswith(str(tmp_path / "cache" / "l2e-studio"))
    assert not beside.exists() and sorted(q.name for q in path.parent.iterdir()) == ["s.dat"]
    np.testing.assert_array_equal(accumulate_events_cached(path), first)
    assert not list(path.parent.glob("*.tmp"))


def test_event_stats(tmp_path: Path, events) -> None:
    x, y, t, p = events
    (tmp_path / "a.raw").write_bytes(pr.encode_evt2(x, y, t, p, W, H))
    s = event_stats(tmp_path / "a.raw", chunk_size=777)
    assert (s.count, s.x_max, s.y_max, s.t_first_us, s.t_last_us, s.on) == (t.size, x.max(), y.max(), t[0], t[-1], p.sum())


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("missing.raw", None, "not found"),
        ("empty.raw", b"", "empty"),
        ("noenc.raw", b"% Date 2020\n% end\n\x00\x00", "names no event encoding"),
        ("evt21.raw", b"% evt 2.1\n% end\n" + b"\x00" * 16, "unsupported event encoding"),
        ("size.dat", b"% Data file containing CD events\n% Version 2\n\x00\x10" + b"\x00" * 32, "event size is 16"),
        ("trunc.dat", b"% Data file containing CD events\n% Version 2\n", "ends before"),
        ("bad.h5", b"\x89HDF\r\n\x1a\nnot really", "HDF5"),
        ("words.txt", b"0.1 1 2 1\n0.2 one 2 0\n", "non-numeric"),
        ("cols.txt", b"0.1 1 2 1\n0.2 1 2\n", "4 columns"),
        ("bad.aedat4", b"#!AER-DAT3.1\r\n", "AEDAT 4.0"),
        ("rec.bag", b"#ROSBAG V2.0\n", "unknown event format"),
    ],
)
def test_bad_event_files(tmp_path: Path, name: str, content: bytes | None, message: str) -> None:
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError, match=message) as info:
        list(iter_events(path))
    assert str(path) in str(info.value)


def test_truncated_raw_decodes_what_is_there(tmp_path: Path, events) -> None:
    data = pr.encode_evt3(*events, W, H)
    path = tmp_path / "cut.raw"
    path.write_bytes(data[: len(data) // 2 + 1])  # odd length: a half word at the end
    got = _collect(path)
    assert 0 < got[0].size < events[0].size
    np.testing.assert_array_equal(got[2], events[2][: got[2].size])


def test_hdf5_missing_fields(tmp_path: Path) -> None:
    with h5py.File(tmp_path / "x.h5", "w") as f:
        f.create_dataset("images", data=np.zeros((2, 2)))
    with pytest.raises(InputError, match="no events found"):
        list(iter_events(tmp_path / "x.h5"))


def test_suffixes() -> None:
    assert {".raw", ".dat", ".aedat4", ".h5", ".hdf5", ".npz", ".npy", ".txt"} <= set(EVENT_SUFFIXES)
