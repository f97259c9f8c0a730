"""The C LZF decoder (python-neo-lzf) and the pure-Python fallback agree bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from l2e_studio.io import _lzf

lzf = pytest.importorskip("lzf")


def _streams():
    rng = np.random.default_rng(0)
    cloud = (rng.normal(size=(50_000, 4)) * [20, 20, 2, 50]).astype("<f4")
    cloud[:, 3] = np.round(np.abs(cloud[:, 3]))
    yield cloud.T.copy().tobytes()  # PCD binary_compressed stores columns
    yield bytes(300_000)  # long overlapping back-references
    yield b"abc" * 10_000 + rng.bytes(5000) + b"xy" * 999


@pytest.mark.parametrize("data", list(_streams()), ids=["cloud", "zeros", "mixed"])
def test_c_and_python_decoders_are_bit_identical(data: bytes) -> None:
    packed = lzf.compress(data)
    assert _lzf._c_lzf is not None  # the dependency is what decodes
    assert _lzf.decompress(packed, len(data)) == data
    assert _lzf._decompress_py(packed, len(data)) == data


@pytest.mark.parametrize("bad", [b"\xff" * 50, b"\x05ab", bytes(np.random.default_rng(1).bytes(300))])
def test_both_decoders_refuse_corrupt_streams(bad: bytes) -> None:
    with pytest.raises(ValueError):
        _lzf.decompress(bad, 1000)
    with pytest.raises(ValueError):
        _lzf._decompress_py(bad, 1000)


def test_a_declared_size_beyond_lzf_expansion_is_refused_before_allocating() -> None:
    with pytest.raises(ValueError, match="cannot expand"):
        _lzf.decompress(b"\x00a", 2**40)
