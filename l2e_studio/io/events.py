"""Raw event recordings -> accumulated event maps (decoders land here; placeholder)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError

EVENT_SUFFIXES: tuple[str, ...] = (".raw", ".dat", ".aedat4", ".h5", ".hdf5", ".npz", ".npy", ".events.txt", ".events.csv")


def accumulate_events_cached(path: str | Path, **kwargs) -> np.ndarray:
    raise InputError(path, "raw event decoding is not available yet")
