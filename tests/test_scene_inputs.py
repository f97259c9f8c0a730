"""Scene folders: ambiguous stems are reported, uninformative scenes are skipped with the reason."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from l2e_studio.checks import MIN_POINTS_IN_IMAGE, check_seed_coverage, seed_coverage
from l2e_studio.errors import InputError
from l2e_studio.geometry import Extrinsic
from l2e_studio.scenes import find_scene_files, load_scene_folder
from l2e_studio.synth import read_truth


def test_a_stem_with_two_scans_is_a_failure_not_a_silent_choice(scene_dir_copy: Path) -> None:
    shutil.copy(scene_dir_copy / "lidar" / "scene_001.txt", scene_dir_copy / "lidar" / "scene_001.csv")
    pairs, _, ambiguous = find_scene_files(scene_dir_copy)
    assert "scene_001" not in pairs and "scene_000" in pairs
    assert "scene_001.txt" in ambiguous["scene_001"] and "scene_001.csv" in ambiguous["scene_001"]
    ss = load_scene_folder(scene_dir_copy, use_cache=False)
    assert "scene_001" not in ss.names and len(ss.names) == 3
    assert [f.name for f in ss.failures] == ["scene_001"] and "share the stem" in ss.failures[0].error


def test_a_constant_map_among_good_scenes_is_skipped_with_the_reason(scene_dir_copy: Path) -> None:
    import cv2

    png = scene_dir_copy / "event" / "scene_002.png"
    cv2.imwrite(str(png), np.zeros_like(cv2.imread(str(png), cv2.IMREAD_UNCHANGED)))
    ss = load_scene_folder(scene_dir_copy, use_cache=False)
    assert "scene_002" not in ss.names
    assert str(png) in ss.failures[0].error and "constant" in ss.failures[0].error


def test_seed_coverage_counts_points_in_the_image(small_synth) -> None:
    scenes, camera, truth = small_synth
    pts = [s.points for s in scenes]
    inside, front, total = seed_coverage(pts, camera, truth)
    assert MIN_POINTS_IN_IMAGE < inside <= front <= total
    assert check_seed_coverage(pts, camera, truth, "seed.yaml") == inside
    flipped = Extrinsic.from_rpy([0, 180, 0], [0, 0, 0]).compose(truth)
    with pytest.raises(InputError, match="seed.yaml: .* behind the camera"):
        check_seed_coverage(pts, camera, flipped, "seed.yaml")


def test_a_non_utf8_file_name_loads_and_is_cached(scene_dir_copy: Path, tmp_path: Path, monkeypatch) -> None:
    import os

    from l2e_studio.cachedir import folder_key, user_cache_dir

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    for sub, ext in (("lidar", "txt"), ("event", "png")):
        os.rename(scene_dir_copy / sub / f"scene_000.{ext}", os.fsencode(scene_dir_copy / sub) + f"/scene_\xff.{ext}".encode("latin-1"))
    for _ in range(2):  # the second load reads the scan cache
        ss = load_scene_folder(scene_dir_copy)
        assert "scene_\udcff" in ss.names and not ss.failures
    cache = user_cache_dir("scans", folder_key(scene_dir_copy))  # the user's cache folder, not the data folder
    assert any(p.name.startswith("scene_\udcff.txt.") for p in cache.iterdir())


def test_extract_refuses_clouds_without_intensity(tmp_path: Path, monkeypatch) -> None:
    """A cloud with no intensity field is an error naming the bag, not an all-zero intensity scan."""
    import l2e_studio.io.lidar as lidar
    from l2e_studio.io.bags import ExtractSettings, extract_bag
    from test_bags import _write

    bag = tmp_path / "a.bag"
    _write(bag, ros2=False)
    monkeypatch.setattr(lidar, "INTENSITY_NAMES", ())  # the bag's "intensity" field is not recognised
    with pytest.raises(InputError, match="a.bag: the point clouds have no intensity field"):
        extract_bag(bag, tmp_path / "out", ExtractSettings())
    assert not list((tmp_path / "out").rglob("*.pcd"))


def test_scenes_from_raw_events_record_their_accumulation_and_can_be_rebuilt(tmp_path: Path, monkeypatch) -> None:
    from app_fixtures import write_event_recordings, write_small_scenes
    from l2e_studio.io.events import Accumulation
    from l2e_studio.scenes import reaccumulate

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    folder = write_small_scenes(tmp_path / "scenes", n_scenes=2)
    shutil.copy(folder / "event" / "scene_001.png", tmp_path / "keep.png")
    write_event_recordings(folder)
    shutil.copy(tmp_path / "keep.png", folder / "event" / "scene_001.png")  # one image map among recordings
    (folder / "event" / "scene_001.npz").unlink()
    ss = load_scene_folder(folder)
    events, image = ss.scenes
    assert events.accumulation == Accumulation() and image.accumulation is None
    w, h = ss.camera.width, ss.camera.height
    short = reaccumulate(events, Accumulation(window_s=0.5, start_s=1.0), w, h)
    assert short.accumulation == Accumulation(0.5, 1.0) and events.accumulation == Accumulation()  # a new scene
    assert short.event_map.sum() < 0.5 * events.event_map.sum() and short.points is events.points
    hot = reaccumulate(events, Accumulation(hot_pixel_sigma=5.0), w, h)
    assert np.count_nonzero(hot.event_map) < np.count_nonzero(events.event_map)  # the hot pixels are zeroed
    with pytest.raises(InputError, match="no events in the window"):
        reaccumulate(events, Accumulation(start_s=60.0), w, h)
    with pytest.raises(ValueError, match="not a raw event recording"):
        reaccumulate(image, Accumulation(), w, h)
    for bad in (dict(window_s=0.0), dict(start_s=-1.0), dict(hot_pixel_sigma=0.0), dict(window_s=float("nan"))):
        with pytest.raises(ValueError):
            Accumulation(**bad)
