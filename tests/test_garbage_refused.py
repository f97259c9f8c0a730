"""Inputs that cannot inform a calibration are refused before the optimiser runs (issue 18):
non-finite event times or coordinates, lidar points beyond any lidar's range, negative map
values, the readers' last tracebacks (ragged text, an .npz that is no zip, HDF5 datasets of the
wrong shape, a file cut inside a record); a map the clip would flatten is rescaled and the
terminal says so. Through the CLI (exit 2, one line naming the file) and the scene loader the
app uses (the bad scene listed with its error, the others loaded).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest

from bad_inputs import assert_one_line_error, run_cli
from l2e_studio.synth import SynthConfig, config_with, write_dataset

TINY = config_with(SynthConfig(), n_scenes=3, width=320, height=180, points_per_scan=4000, seed=5)
RSS_BOUND_MB = 400


@pytest.fixture(scope="module")
def tiny_dir(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("tiny") / "scenes", TINY)


@pytest.fixture
def scenes(tiny_dir, tmp_path) -> Path:
    shutil.copytree(tiny_dir, tmp_path / "scenes", ignore=shutil.ignore_patterns(".l2e_cache"))
    return tmp_path / "scenes"


# --- damage to one scene (returns the file the error must name) ------------------------------

def _scan_table(folder: Path, i: int) -> tuple[Path, np.ndarray]:
    f = folder / "lidar" / f"scene_{i:03d}.txt"
    return f, np.loadtxt(f, delimiter=",")


def scan_far(folder: Path, i: int) -> Path:
    f, table = _scan_table(folder, i)
    table[::500, :3] = 1e30  # 8 of 4000 points
    np.savetxt(f, table, delimiter=",", fmt="%.6g")
    return f


def scan_ragged_fits(folder: Path, i: int) -> Path:
    """Line 2 lost a value and line 3 gained one: the total is still 4 x lines."""
    f = folder / "lidar" / f"scene_{i:03d}.txt"
    lines = f.read_text().splitlines()
    lines[1] = lines[1].rsplit(",", 1)[0]
    lines[2] = lines[2] + ",7"
    f.write_text("\n".join(lines) + "\n")
    return f


def scan_text_field(folder: Path, i: int) -> Path:
    f = folder / "lidar" / f"scene_{i:03d}.txt"
    lines = f.read_text().splitlines()
    lines[10] = lines[10].replace(",", ",high,", 1).rsplit(",", 1)[0]
    f.write_text("\n".join(lines) + "\n")
    return f


def scan_npz_not_zip(folder: Path, i: int) -> Path:
    f = folder / "lidar" / f"scene_{i:03d}.txt"
    f.unlink()
    out = f.with_suffix(".npz")
    out.write_bytes(b"PK\x03\x04" + bytes(200))  # a zip signature and nothing behind it
    return out


def scan_ply_cut_in_a_record(folder: Path, i: int) -> Path:
    f, table = _scan_table(folder, i)
    f.unlink()
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(table)}\nproperty float x\nproperty float y\n"
            "property float z\nproperty float intensity\nend_header\n").encode()
    out = f.with_suffix(".ply")
    out.write_bytes(head + table.astype("<f4").tobytes()[:-7])  # the file ends inside the last point
    return out


def _map(folder: Path, i: int) -> tuple[Path, np.ndarray]:
    f = folder / "event" / f"scene_{i:03d}.png"
    return f, cv2.imread(str(f), cv2.IMREAD_UNCHANGED).astype(np.float32)


def map_negative(folder: Path, i: int) -> Path:
    f, m = _map(folder, i)
    f.unlink()
    m[::7, ::5] = -3.0
    np.save(f.with_suffix(".npy"), m)
    return f.with_suffix(".npy")


def map_nan(folder: Path, i: int) -> Path:
    f, m = _map(folder, i)
    f.unlink()
    m[3, 4] = np.nan
    out = f.with_suffix(".tiff")
    cv2.imwrite(str(out), m)
    return out


def saturated_16bit(folder: Path, i: int) -> Path:
    """The map as 16-bit counts x 40: nearly every firing pixel above the clip of 127."""
    f, m = _map(folder, i)
    cv2.imwrite(str(f), np.clip(m * 40, 0, 65535).astype(np.uint16))
    return f


ONE_SCENE = {
    "lidar-1e30": (scan_far, ["farther than 10 km"]),
    "lidar-ragged-total-fits": (scan_ragged_fits, ["line 2 has 3 columns"]),
    "lidar-text-field": (scan_text_field, ["not numeric"]),
    "lidar-npz-not-zip": (scan_npz_not_zip, ["not a zip archive"]),
    "lidar-ply-cut-in-a-record": (scan_ply_cut_in_a_record, ["truncated"]),
    "map-negative": (map_negative, ["negative"]),
    "map-nan": (map_nan, ["NaN"]),
}


def _every_scene(damage: Callable[[Path, int], Path], folder: Path) -> Path:
    named = [damage(folder, i) for i in range(TINY.n_scenes)]
    return named[0]


@pytest.mark.parametrize("name", sorted(ONE_SCENE))
def test_calibrate_refuses_before_optimising(name: str, scenes: Path) -> None:
    damage, fragments = ONE_SCENE[name]
    named = _every_scene(damage, scenes)
    run = run_cli("calibrate", "--scenes", scenes, "--quiet", "--out", scenes.parent / "r.yaml", cwd=scenes.parent)
    assert_one_line_error(run, named.name, *fragments)
    assert run.peak_rss_mb < RSS_BOUND_MB
    assert not (scenes.parent / "r.yaml").exists()


@pytest.mark.parametrize("name", sorted(ONE_SCENE))
def test_the_loader_lists_the_bad_scene_and_keeps_the_others(name: str, scenes: Path) -> None:
    """What the app loads a folder with: the damaged scene is a failure naming its file and the
    problem; the other scenes load as they did."""
    from l2e_studio.scenes import load_scene_folder

    damage, fragments = ONE_SCENE[name]
    named = damage(scenes, 1)
    ss = load_scene_folder(scenes, use_cache=False)
    assert ss.names == ["scene_000", "scene_002"]
    assert len(ss.failures) == 1 and ss.failures[0].name == "scene_001"
    line = ss.failures[0].error
    assert str(named) in line and "\n" not in line
    for frag in fragments:
        assert frag in line


def test_a_saturated_16_bit_map_is_rescaled_and_said(scenes: Path) -> None:
    from l2e_studio.scenes import load_scene_folder

    before = load_scene_folder(scenes, use_cache=False).scenes[0].event_map
    named = saturated_16bit(scenes, 0)
    raw = cv2.imread(str(named), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and np.mean(raw[raw > 0] > 127) > 0.5  # the clip alone would flatten it
    ss = load_scene_folder(scenes, use_cache=False)
    scene = ss.scenes[0]
    assert scene.map_scale < 0.05
    fired = before > 0
    assert np.mean(scene.event_map[fired] > 127) <= 0.011  # ~1 % above the clip, as the paper's few wild pixels
    # the rescaled map orders pixels as the original counts did
    assert np.corrcoef(scene.event_map[fired], before[fired])[0, 1] > 0.99
    assert any("rescaled" in n and str(named) in n for n in ss.notes)
    run = run_cli("calibrate", "--scenes", scenes, "--quiet", "--single-stage", "--out", scenes.parent / "r.yaml",
                  cwd=scenes.parent)
    assert run.returncode == 0, run.stderr
    assert any(ln.startswith("note:") and "rescaled" in ln and named.name in ln for ln in run.stderr.splitlines())


# --- raw events through accumulate --------------------------------------------------------

def _events(n: int = 200_000, **change) -> dict:
    rng = np.random.default_rng(3)
    ev = {"x": rng.integers(0, 320, n), "y": rng.integers(0, 180, n), "t": np.sort(rng.uniform(0, 2.0, n)),
          "p": rng.integers(0, 2, n), "sensor_size": np.array([320, 180])}
    for key, fn in change.items():
        ev[key] = fn(ev[key])
    return ev


def _poke(values, at, value):
    def fn(a):
        a = a.astype(np.float64)
        a[list(at)] = value
        return a
    return fn


def _h5(write: Callable) -> Callable[[Path], Path]:
    def build(raw: Path) -> Path:
        import h5py

        with h5py.File(raw / "a.h5", "w") as f:
            write(f)
        return raw / "a.h5"
    return build


def _h5_events(f, **change) -> None:
    ev = _events(2000)
    ev.pop("sensor_size")
    ev["t"] = (ev["t"] * 1e6).astype(np.int64)
    ev.update(change)
    g = f.create_group("events")
    for k, v in ev.items():
        g.create_dataset(k, data=v)


def _npz(name: str, **arrays) -> Callable[[Path], Path]:
    def build(raw: Path) -> Path:
        np.savez(raw / name, **arrays)
        return raw / name
    return build


def _bytes(name: str, data: bytes) -> Callable[[Path], Path]:
    def build(raw: Path) -> Path:
        (raw / name).write_bytes(data)
        return raw / name
    return build


EVENT_CASES = {
    "events-2-nan-times-in-200000": (_npz("a.npz", **_events(t=_poke(None, (1000, 150_000), np.nan))),
                                     ["2 of 200000 event times are NaN or infinite"]),
    "events-inf-time": (_npz("a.npz", **_events(t=_poke(None, (5,), np.inf))), ["NaN or infinite"]),
    "events-inf-x": (_npz("a.npz", **_events(x=_poke(None, (9, 99), np.inf))), ["2 of 200000 events have NaN or infinite"]),
    "events-text-nan-time": (_bytes("a.txt", b"0.1 5 6 1\nnan 5 6 0\n0.3 7 8 1\n"), ["NaN or infinite"]),
    "events-text-time-1e30": (_bytes("a.txt", b"0.1 5 6 1\n1e30 5 6 0\n"), ["beyond any clock"]),
    "events-text-ragged": (_bytes("a.txt", b"0.1 5 6 1\n0.2 5 6\n0.3 5 6 1 1\n"), ["line 2 has 3 columns"]),
    "events-npz-not-zip": (_bytes("a.npz", b"\x93NUMPY garbage" * 20), ["not a zip archive"]),
    "h5-scalar-datasets": (_h5(lambda f: _h5_events(f, x=5, y=5, t=5, p=1)), ["1-D dataset"]),
    "h5-2d-times": (_h5(lambda f: _h5_events(f, t=np.zeros((2000, 2), np.int64))), ["/events/t", "(2000, 2)"]),
    "h5-t-offset-array": (_h5(lambda f: (_h5_events(f), f.create_dataset("t_offset", data=np.arange(3)))),
                          ["t_offset must be one number"]),
    "h5-string-polarity": (_h5(lambda f: _h5_events(f, p=np.array([b"on"] * 2000))), ["polarities"]),
}


@pytest.mark.parametrize("name", sorted(EVENT_CASES))
def test_accumulate_refuses_garbage_events(name: str, tmp_path: Path) -> None:
    build, fragments = EVENT_CASES[name]
    raw = tmp_path / "ev" / "events_raw"
    raw.mkdir(parents=True)
    named = build(raw)
    run = run_cli("accumulate", tmp_path / "ev", cwd=tmp_path)
    assert_one_line_error(run, str(named), *fragments)
    assert run.peak_rss_mb < RSS_BOUND_MB
    assert not list((tmp_path / "ev").glob("event/*.png"))


def test_a_zero_norm_quaternion_seed_is_refused(scenes: Path) -> None:
    seed = scenes.parent / "tf.txt"
    seed.write_text("ros2 run tf2_ros static_transform_publisher --x 0 --y 0 --z 0 --qx 0 --qy 0 --qz 0 --qw 0 "
                    "--frame-id camera --child-frame-id lidar\n")
    run = run_cli("calibrate", "--scenes", scenes, "--seed", seed, "--quiet", "--out", scenes.parent / "r.yaml",
                  cwd=scenes.parent)
    assert_one_line_error(run, str(seed), "zero norm")


# --- bags through extract ----------------------------------------------------------------------

def _bag_far_points(path: Path) -> Path:
    from bag_files import PTS, write_bag

    far = PTS.copy()
    far[::10, 0] = 1e30
    write_bag(path, ros2=False, points=far)
    return path


def _bag_cut_in_a_record(path: Path) -> Path:
    from bag_files import write_bag

    write_bag(path, ros2=False)
    path.write_bytes(path.read_bytes()[:-300])  # the index at the end loses its last records
    return path


def _bag_record_lies(path: Path) -> Path:
    import struct

    from bag_files import write_bag

    write_bag(path, ros2=False)
    data = bytearray(path.read_bytes())
    start = len(b"#ROSBAG V2.0\n")
    data[start:start + 4] = struct.pack("<I", 2**31)  # the first record's header claims 2 GB
    path.write_bytes(bytes(data))
    return path


BAG_CASES = {
    "bag-cloud-1e30": (_bag_far_points, ["farther than 10 km"]),
    "bag-cut-in-a-record": (_bag_cut_in_a_record, ["truncated"]),
    "bag-record-length-lies": (_bag_record_lies, ["2147483648-byte header"]),
}


@pytest.mark.parametrize("name", sorted(BAG_CASES))
def test_extract_refuses_garbage_bags(name: str, tmp_path: Path) -> None:
    build, fragments = BAG_CASES[name]
    bag = build(tmp_path / "a.bag")
    run = run_cli("extract", bag, "--out", tmp_path / "out", cwd=tmp_path)
    assert_one_line_error(run, str(bag), *fragments)
    assert run.peak_rss_mb < RSS_BOUND_MB
    assert not list(tmp_path.glob("out/lidar/*"))
