"""The calibration board: what ``target.yaml`` describes, and its geometry in its own frame.

Board frame: origin at the board's centre, x along the columns (the board's width), y along
the rows (its height), z = x cross y (OpenCV's object-point convention: it points away from a
camera that sees the pattern). The inner corners
and the outline are centred on the origin, so the 180 deg ambiguity of a symmetric grid's corner
order (OpenCV may number it from either end) changes neither the board's plane nor its outline.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from ..errors import InputError
from ..io.safe_load import parse_yaml, read_text_capped

TARGET_KINDS = ("checkerboard",)
TARGET_FILES = ("target.yaml", "target.yml")
EXPECTED = ("expected `target: {kind: checkerboard, squares: [columns, rows], square_m: side of a square in metres, "
            "size_m: [width, height] (optional, outer size with the margin)}`")


@dataclass(frozen=True)
class Board:
    """A checkerboard: ``squares`` = (columns, rows) of squares (not inner corners), ``square_m`` the
    side of one square, ``size_m`` = (width, height) of the whole board, margin included (the
    printed grid alone when the file does not say)."""

    kind: str
    squares: tuple[int, int]
    square_m: float
    size_m: tuple[float, float]

    @property
    def inner(self) -> tuple[int, int]:
        """Inner corners (columns, rows): OpenCV's ``patternSize``."""
        return self.squares[0] - 1, self.squares[1] - 1

    def corners(self) -> np.ndarray:
        """(N, 3) inner corners in the board frame (row-major, as OpenCV returns them)."""
        nc, nr = self.inner
        i, j = np.meshgrid(np.arange(nc), np.arange(nr))
        x = (i.ravel() - (nc - 1) / 2.0) * self.square_m
        y = (j.ravel() - (nr - 1) / 2.0) * self.square_m
        return np.column_stack([x, y, np.zeros_like(x)])

    def outline(self) -> np.ndarray:
        """(4, 3) corners of the board's outer edge in the board frame."""
        w, h = self.size_m[0] / 2.0, self.size_m[1] / 2.0
        return np.array([[-w, -h, 0.0], [w, -h, 0.0], [w, h, 0.0], [-w, h, 0.0]])

    @property
    def diagonal_m(self) -> float:
        return float(np.hypot(*self.size_m))

    def to_dict(self) -> dict:
        return {"kind": self.kind, "squares": list(self.squares), "square_m": self.square_m,
                "size_m": list(self.size_m)}


def find_target(folder: str | Path) -> Path | None:
    """The ``target.yaml`` of a scene folder, or None."""
    for name in TARGET_FILES:
        if (Path(folder) / name).is_file():
            return Path(folder) / name
    return None


def load_target(path: str | Path) -> Board:
    """Read a board file; anything else is one :class:`InputError` naming the file and what was expected."""
    path = Path(path)
    try:
        doc = parse_yaml(path, read_text_capped(path, what="target file"))
    except yaml.YAMLError as exc:
        raise InputError(path, f"not valid YAML ({str(exc).splitlines()[0]}); {EXPECTED}") from None
    if isinstance(doc, dict) and isinstance(doc.get("target"), dict):
        doc = doc["target"]
    if not isinstance(doc, dict):
        raise InputError(path, f"not a board description; {EXPECTED}")
    kind = doc.get("kind")
    if kind not in TARGET_KINDS:
        raise InputError(path, f"kind is {kind!r}, expected one of {', '.join(TARGET_KINDS)}; {EXPECTED}")
    squares = doc.get("squares")
    if (not isinstance(squares, (list, tuple)) or len(squares) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) for v in squares)
            or min(squares) < 3 or max(squares) > 100):
        raise InputError(path, f"squares is {squares!r}, expected [columns, rows]: two whole numbers of squares, "
                               f"3..100 each")
    square = _positive(path, doc.get("square_m"), "square_m", 0.001, 2.0)
    grid = (squares[0] * square, squares[1] * square)
    size = doc.get("size_m")
    if size is None:
        size_m = grid
    else:
        if not isinstance(size, (list, tuple)) or len(size) != 2:
            raise InputError(path, f"size_m is {size!r}, expected [width, height] in metres")
        size_m = (_positive(path, size[0], "size_m width", 0.001, 20.0), _positive(path, size[1], "size_m height", 0.001, 20.0))
        if size_m[0] < grid[0] - 1e-6 or size_m[1] < grid[1] - 1e-6:
            raise InputError(path, f"size_m {list(size_m)} is smaller than the printed grid "
                                   f"({grid[0]:.3f} x {grid[1]:.3f} m = squares x square_m)")
    return Board("checkerboard", (int(squares[0]), int(squares[1])), square, (float(size_m[0]), float(size_m[1])))


def _positive(path: Path, value, what: str, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or not low <= value <= high:
        raise InputError(path, f"{what} is {value!r}, expected a number of metres in [{low:g}, {high:g}]")
    return float(value)
