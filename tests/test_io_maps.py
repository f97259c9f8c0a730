"""Map loading: event maps vs camera frames, grey conversion, size and corruption checks."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from l2e_studio.errors import InputError
from l2e_studio.io.maps import MAP_SUFFIXES, guess_kind, load_map, write_map_png


def _counts(h: int = 48, w: int = 64) -> np.ndarray:
    """Event counts as real accumulated maps have them: most pixels never fire (63-84 % zeros in
    the real recordings), the rest 1..127 (a map with almost no empty pixel reads as a photo)."""
    rng = np.random.default_rng(1)
    counts = rng.integers(1, 128, size=(h, w))
    counts[rng.random((h, w)) < 0.7] = 0
    return counts.astype(np.uint8)


def test_event_png_under_event_folder(tmp_path: Path) -> None:
    counts = _counts()
    path = write_map_png(tmp_path / "event" / "0001.png", counts)
    image, kind = load_map(path, width=64, height=48)
    assert kind == "events" and image.dtype == np.float32 and image.shape == (48, 64)
    np.testing.assert_array_equal(image, counts)


def test_sixteen_bit_tiff_keeps_raw_counts(tmp_path: Path) -> None:
    counts = (_counts().astype(np.uint16) * 300)
    path = tmp_path / "scene_events.tiff"
    assert cv2.imwrite(str(path), counts)
    image, kind = load_map(path)
    assert kind == "events"
    np.testing.assert_array_equal(image, counts.astype(np.float32))


def test_colour_and_jpeg_are_images_converted_to_grey(tmp_path: Path) -> None:
    bgr = np.zeros((30, 40, 3), np.uint8)
    bgr[..., 0], bgr[..., 1], bgr[..., 2] = 10, 100, 200
    png = tmp_path / "event" / "frame.png"  # colour wins over the folder name
    png.parent.mkdir()
    cv2.imwrite(str(png), bgr)
    image, kind = load_map(png)
    assert kind == "image" and image.shape == (30, 40)
    expected = 0.114 * 10 + 0.587 * 100 + 0.299 * 200
    np.testing.assert_allclose(image, expected, atol=0.6)
    jpg = tmp_path / "cam.jpg"
    cv2.imwrite(str(jpg), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))
    assert load_map(jpg)[1] == "image"


def test_grey_png_kind_from_name_and_override(tmp_path: Path) -> None:
    path = tmp_path / "images" / "cam0.png"
    path.parent.mkdir()
    cv2.imwrite(str(path), _counts())
    assert load_map(path)[1] == "image"
    assert load_map(path, kind="events")[1] == "events"
    assert guess_kind(tmp_path / "events" / "x.png") == "events"
    with pytest.raises(ValueError):
        load_map(path, kind="lidar")


def test_the_image_folder_decides_even_in_a_data_set_named_event(tmp_path: Path) -> None:
    # a sparse grey frame (mostly black, few levels) under rig_event/image/ is a camera image:
    # the map folder names the kind, not the data set's folder
    path = tmp_path / "lcecalib_rles01_event" / "image" / "00000.png"
    path.parent.mkdir(parents=True)
    cv2.imwrite(str(path), _counts())
    assert guess_kind(path) == "image" and load_map(path)[1] == "image"
    assert guess_kind(tmp_path / "rig" / "event" / "00000.png") == "events"
    assert guess_kind(tmp_path / "rig_event" / "maps" / "00000.png") == "events"


def test_2d_npy_map(tmp_path: Path) -> None:
    counts = _counts().astype(np.float32) * 1.5
    np.save(tmp_path / "event_0.npy", counts)
    image, kind = load_map(tmp_path / "event_0.npy")
    assert kind == "events"
    np.testing.assert_array_equal(image, counts)


def test_size_mismatch_names_both_sizes(tmp_path: Path) -> None:
    path = write_map_png(tmp_path / "event" / "a.png", _counts(48, 64))
    with pytest.raises(InputError, match="map is 64x48, camera expects 1280x720"):
        load_map(path, width=1280, height=720)


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("missing.png", None, "not found"),
        ("empty.png", b"", "empty"),
        ("corrupt.png", b"\x89PNG\r\n\x1a\nthis is not a png", "cannot decode"),
        ("map.gif", b"GIF89a", "unknown map format"),
    ],
)
def test_bad_maps(tmp_path: Path, name: str, content: bytes | None, message: str) -> None:
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError, match=message):
        load_map(path)


def test_truncated_png(tmp_path: Path) -> None:
    good = write_map_png(tmp_path / "good.png", _counts(200, 300))
    bad = tmp_path / "trunc.png"
    bad.write_bytes(good.read_bytes()[:200])
    with pytest.raises(InputError, match="cannot decode"):
        load_map(bad)


def test_suffixes_cover_images_and_raw_events() -> None:
    for s in (".png", ".jpg", ".tiff", ".raw", ".dat", ".aedat4", ".h5"):
        assert s in MAP_SUFFIXES
