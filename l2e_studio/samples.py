"""Where the embedded sample scenes live (``assets/sample`` at the top of the source tree)."""

from __future__ import annotations

from pathlib import Path

from .errors import InputError


def sample_scenes_dir() -> Path:
    """The embedded sample scene folder, so the app and ``calibrate`` run with no data."""
    path = Path(__file__).resolve().parent.parent / "assets" / "sample"
    if not path.is_dir():
        raise InputError(path, "embedded sample scenes not found; install from a source checkout "
                               "(pip install -e .) or pass --scenes DIR")
    return path
