"""The compiled EVT 2.0 / 3.0 decoders give event for event what the numpy decoders they replaced
gave (tests/evt_reference.py): on the real samples, on synthetic streams holding every word type,
and wherever the stream is cut (file chunks, bag packets, a full output buffer)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import REALDATA

import evt_reference as ref
from l2e_studio.io import event_codecs as codecs
from l2e_studio.io import event_prophesee as pr

SAMPLES = REALDATA / "event_camera_samples"


def _join(pieces) -> list[np.ndarray]:
    return list(codecs.concat(list(pieces)))


def _assert_same(a, b) -> None:
    assert [x.dtype for x in a] == [x.dtype for x in b]
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)


def _evt3_stream(n: int, seed: int) -> np.ndarray:
    """Random EVT 3.0 words of every type: y, x, vector base, VECT_12, VECT_8, time low, time high
    (running up and wrapping past 4095), and the non-pixel types (0x7, 0xA, 0xE, 0xF, 0x1)."""
    rng = np.random.default_rng(seed)
    kinds = rng.choice([0x0, 0x2, 0x3, 0x4, 0x5, 0x6, 0x8, 0x7, 0xA, 0xE, 0xF, 0x1], n,
                       p=[.14, .2, .1, .14, .1, .1, .06, .03, .03, .03, .04, .03])
    payload = rng.integers(0, 4096, n)
    th = np.flatnonzero(kinds == 0x8)
    payload[th] = np.cumsum(rng.integers(0, 700, th.size)) % 4096  # rising, wrapping high time
    return ((kinds << 12) | payload).astype(np.uint16)


def _evt2_stream(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    kinds = rng.choice([0x0, 0x1, 0x8, 0xA, 0xE, 0xF], n, p=[.35, .35, .15, .05, .05, .05])
    return ((kinds.astype(np.uint32) << 28) | rng.integers(0, 2**28, n).astype(np.uint32)).astype(np.uint32)


def _ref_evt3(words: np.ndarray) -> list[np.ndarray]:
    return list(ref._evt3_chunk(words, ref._Evt3State(), np.arange(12, dtype=np.uint16)))


def _ref_evt2(words: np.ndarray, tmp_path: Path) -> list[np.ndarray]:
    path = tmp_path / "ref2.raw"
    path.write_bytes(words.astype("<u4").tobytes())
    return _join(ref.decode_evt2(path, 0, 1 << 20))


@pytest.mark.parametrize("seed", range(4))
def test_evt3_synthetic_streams_match_the_numpy_decoder(seed: int) -> None:
    words = _evt3_stream(20_000, seed)
    expected = _ref_evt3(words)
    assert expected[0].size > 20_000  # vectors expand to many events
    _assert_same(_join(codecs.Evt3Decoder().decode(words)), expected)
    _assert_same(_join(codecs.Evt3Decoder(capacity=64).decode(words)), expected)  # output split many times


@pytest.mark.parametrize("seed", range(3))
def test_evt2_synthetic_streams_match_the_numpy_decoder(seed: int, tmp_path: Path) -> None:
    words = _evt2_stream(20_000, seed)
    expected = _ref_evt2(words, tmp_path)
    assert expected[0].size > 10_000
    _assert_same(_join(codecs.Evt2Decoder().decode(words)), expected)
    _assert_same(_join(codecs.Evt2Decoder(capacity=64).decode(words)), expected)


def test_a_cut_at_every_offset_gives_the_same_events() -> None:
    """One decoder fed the stream in two pieces, cut at every word and at every byte."""
    words = _evt3_stream(300, 7)
    expected = _ref_evt3(words)
    for k in range(words.size + 1):
        dec = codecs.Evt3Decoder(capacity=64)
        _assert_same(_join([*dec.decode(words[:k]), *dec.decode(words[k:])]), expected)
    data = words.astype("<u2").tobytes()
    for k in range(len(data) + 1):
        dec = codecs.Evt3Decoder(capacity=64)
        _assert_same(_join([*dec.decode_bytes(data[:k]), *dec.decode_bytes(data[k:])]), expected)
    words2 = _evt2_stream(200, 8)
    expected2 = _join(codecs.Evt2Decoder().decode(words2))
    data2 = words2.astype("<u4").tobytes()
    for k in range(len(data2) + 1):
        dec = codecs.Evt2Decoder(capacity=64)
        _assert_same(_join([*dec.decode_bytes(data2[:k]), *dec.decode_bytes(data2[k:])]), expected2)


@pytest.mark.parametrize("chunk", [1, 7, 4096])
def test_file_decoding_in_chunks_matches_the_numpy_decoder(tmp_path: Path, chunk: int) -> None:
    rng = np.random.default_rng(3)
    n = 5000
    t = np.sort(rng.integers(0, 40_000_000, n))  # past the 24-bit EVT 3.0 wrap
    x, y, p = rng.integers(0, 640, n), rng.integers(0, 480, n), rng.integers(0, 2, n)
    for name, data, new, old in (("a.raw", pr.encode_evt3(x, y, t, p, 640, 480), pr.decode_evt3, ref.decode_evt3),
                                 ("b.raw", pr.encode_evt2(x, y, t, p, 640, 480), pr.decode_evt2, ref.decode_evt2)):
        path = tmp_path / name
        path.write_bytes(data)
        header = pr.read_header(path)
        got = _join(new(path, header, chunk))
        _assert_same(got, _join(old(path, header.data_offset, 4096)))
        np.testing.assert_array_equal(got[2], t)


@pytest.mark.realdata
@pytest.mark.parametrize("name", ["evt2.raw", "evt3_sample.raw"])
def test_real_samples_match_the_numpy_decoder(name: str) -> None:
    path = SAMPLES / name
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    header = pr.read_header(path)
    new, old = (pr.decode_evt2, ref.decode_evt2) if header.encoding == "evt2" else (pr.decode_evt3, ref.decode_evt3)
    expected = _join(old(path, header.data_offset, 1 << 20))
    assert expected[0].size > 200_000
    for chunk in (1000, 65_536, 1 << 20):
        _assert_same(_join(new(path, header, chunk)), expected)
