"""A shaken board's event map made a checkerboard picture again: the cells between its event
lines two-coloured.

A board shaken before an event camera fires events where its brightness changes: at the
squares' edges and the board's outline. The accumulated (unsigned) map is a grid of bright lines
on a dark field, black and white squares alike empty, so no chessboard detector sees a
checkerboard in it. Here the cells are recovered and two-coloured:

1. the crop around the board is upscaled (cubic) so that a cell, the lines' period (the power
   spectrum's peak), spans ~``CELL_PX``;
2. the lines: brighter than a factor of the local mean (over 1.5 cells) and than a quarter of
   Otsu's threshold (noise events); what is left between them, eroded a little (lines crossing
   at a corner leave gaps), are the cells' cores (4-connected; specks dropped);
3. every pixel goes to the nearest core; two cells are neighbours when they share a border of
   most of a side (cells meeting at a corner share a point);
4. the neighbour graph is two-coloured breadth-first; the cell on most conflicts (an odd cycle:
   a line missing where the shake ran along it merges cells of both colours) is dropped and the
   rest coloured again; only the largest consistent group is kept;
5. an event counts a step in log intensity, so the lines spread further into the dark squares
   than into the light ones and the plain split in 3 makes one colour's cells smaller: the split
   is shifted by the one offset that gives both colours the same mean cell area, and 3-4 are
   repeated on that split;
6. the picture: a soft step at the split, mid-grey where uncoloured. A corner there is where the
   edges' mean positions over the shake cross: the board's pose on average.

The quad detector then needs the full inner-corner grid and the pose its reprojection, as for
any image (:mod:`.detect`, stage 5); a map whose lines do not two-colour into the board's grid is
not found, nothing is guessed. Measured on synthetic shaken boards (``events-moving``): found
where both edge families fired, corners ~0.2 px RMS from the truth; ``benchmarks/bench_target.py``.
"""

from __future__ import annotations

from collections import deque

import cv2
import numpy as np
from scipy import ndimage

#: (line threshold over the local mean, erosion in cells) tried in turn
TRIALS = ((0.7, 0.1), (0.6, 0.05), (1.0, 0.05), (0.5, 0.1), (0.8, 0.05), (0.4, 0.1))
#: the map is upscaled so that a cell spans about this many pixels (cubic)
CELL_PX = 24
#: the synthetic picture's blur (in cells): a step the corner refinement can centre on
BLUR_CELLS = 0.04
#: neighbours share a border at least this share of the smaller cell's side
MIN_SHARED_SIDE = 0.65
#: colourings, each on the cells split where the last one's colours balance
PASSES = 3
#: a map with more cells than this many times the board's squares is no board's lines
MAX_CELLS = 4
#: the upscaled crop's longest side (px) at most
MAX_SIDE = 1600
#: a core smaller than this share of a cell's area is speckle
MIN_CORE_SHARE = 0.01


def line_period(grey: np.ndarray) -> float:
    """The spacing of the event lines in ``grey`` (px): the strongest spatial frequency of its
    power spectrum, the slowest few left out (the board's outline, the crop's size)."""
    img = grey.astype(np.float32) - grey.mean()
    h, w = img.shape
    power = np.abs(np.fft.rfft2(img * np.outer(np.hanning(h), np.hanning(w)))) ** 2
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.rfftfreq(w)[None, :]
    f = np.hypot(fx, fy)
    power[(f < 3.0 / max(h, w)) | (f > 0.4)] = 0
    return float(1.0 / f.ravel()[np.argmax(power)])


def upscale(grey: np.ndarray) -> tuple[np.ndarray, int, float]:
    """``grey`` (a crop around the board) upscaled so that a cell (the lines' period) spans
    about ``CELL_PX``; the factor (1..6) and the cell's side there (px)."""
    period = line_period(grey)
    scale = int(np.clip(min(round(CELL_PX / period), MAX_SIDE // max(grey.shape)), 1, 6))
    if scale == 1:
        return grey, 1, period
    return cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC), scale, period * scale


def line_mask(grey: np.ndarray, cell: float, local: float) -> np.ndarray:
    """bool (H, W): the event lines of ``grey`` (upscaled, a cell ~``CELL_PX``): brighter than
    ``local`` x the mean over 1.5 cells (blurred by 1/12 of a cell) and than a quarter of
    Otsu's threshold (noise events and the dark field)."""
    blurred = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), cell / 12)
    t, _ = cv2.threshold(np.clip(blurred, 0, 255).astype(np.uint8), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    window = int(1.5 * cell) | 1
    return (blurred > local * cv2.blur(blurred, (window, window))) & (blurred > max(2.0, 0.25 * t))


def cell_cores(lines: np.ndarray, cell: float, erode: int) -> tuple[np.ndarray, int]:
    """``(cores, n)``: what is left between the lines, eroded by ``erode`` px, labelled
    (4-connected, 1..n-1; specks under ``MIN_CORE_SHARE`` of a cell and the lines are 0)."""
    free = (~lines).astype(np.uint8)
    if erode:
        free = cv2.erode(free, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * erode + 1,) * 2))
    n, cores, stats, _ = cv2.connectedComponentsWithStats(free, connectivity=4)
    small = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] < MIN_CORE_SHARE * cell**2)
    cores[np.isin(cores, small[small > 0])] = 0
    return cores, n


def touching_border(labels: np.ndarray, n: int) -> np.ndarray:
    """Per label: whether it reaches the crop's border (the room around the board)."""
    out = np.zeros(n, bool)
    out[np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])] = True
    return out


def partition(cores: np.ndarray, black: np.ndarray, white: np.ndarray, shift: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Every pixel given to the nearest core; the distances to black cores less ``shift / 2``,
    to white ones more (the lines spread further into the dark squares, see :func:`balance`),
    to uncoloured ones plain. ``black``/``white``: per-label flags. Returns the labels and
    ``f = d_black - d_white - shift`` (negative: black; +-inf where a colour has no core)."""
    best = np.full(cores.shape, np.inf)
    labels = np.zeros(cores.shape, np.int32)
    dists = []
    for flags, offset in ((black, -shift / 2), (white, shift / 2), (~(black | white), 0.0)):
        mask = flags[cores] & (cores > 0)
        if not mask.any():
            dists.append(np.full(cores.shape, np.inf))
            continue
        dist, (iy, ix) = ndimage.distance_transform_edt(~mask, return_indices=True)
        dists.append(dist)
        closer = dist + offset < best
        best[closer] = dist[closer] + offset
        labels[closer] = cores[iy, ix][closer]
    with np.errstate(invalid="ignore"):
        return labels, dists[0] - dists[1] - shift


def neighbours(labels: np.ndarray, n: int, cell: float) -> dict[int, set[int]]:
    """Regions sharing a border longer than ``MIN_SHARED_SIDE`` of a cell's side ``cell`` (px)."""
    pairs = []
    for a, b in ((labels[:, :-1], labels[:, 1:]), (labels[:-1], labels[1:])):
        m = (a != b) & (a > 0) & (b > 0)
        lo, hi = np.minimum(a[m], b[m]), np.maximum(a[m], b[m])
        pairs.append(lo.astype(np.int64) * n + hi)
    keys, counts = np.unique(np.concatenate(pairs), return_counts=True)
    graph: dict[int, set[int]] = {}
    for key, c in zip(keys, counts):
        a, b = divmod(int(key), n)
        if c >= MIN_SHARED_SIDE * cell:
            graph.setdefault(a, set()).add(b)
            graph.setdefault(b, set()).add(a)
    return graph


def two_colour(graph: dict[int, set[int]], area: np.ndarray, max_drops: int = 1000) -> dict[int, int]:
    """Colour 0/1 of the largest group of cells two-coloured without conflict: while some
    neighbours share a colour (an odd cycle: a line missing), the cell on most conflicts is
    dropped and the rest coloured again; more than ``max_drops`` such cells: nothing ({})."""
    dropped: set[int] = set()
    while len(dropped) <= max_drops:
        colour: dict[int, int] = {}
        group: dict[int, int] = {}
        conflicts: dict[int, int] = {}
        for start in graph:
            if start in dropped or start in colour:
                continue
            colour[start], group[start] = 0, start
            queue = deque([start])
            while queue:
                a = queue.popleft()
                for b in graph[a]:
                    if b in dropped:
                        continue
                    if b not in colour:
                        colour[b], group[b] = 1 - colour[a], start
                        queue.append(b)
                    elif colour[b] == colour[a]:
                        conflicts[a] = conflicts.get(a, 0) + 1
        if not conflicts:
            break
        dropped.add(max(conflicts, key=lambda c: (conflicts[c], area[c])))
    else:
        return {}
    if not group:
        return {}
    roots, sizes = np.unique(list(group.values()), return_counts=True)
    best = roots[np.argmax(sizes)]
    return {c: colour[c] for c, g in group.items() if g == best}


def balance(labels: np.ndarray, f: np.ndarray, black: np.ndarray, white: np.ndarray, skip: np.ndarray,
            cell: float) -> float:
    """The shift of every black/white edge (px, along ``f``) that gives black and white cells
    the same mean area, as a checkerboard's squares have; cells flagged in ``skip`` (the margin
    around the squares, the room) are left out."""
    keep = (black | white) & ~skip
    inside = keep[labels]
    g = f[inside]
    n_black, n_white = max(1, int((black & keep).sum())), max(1, int((white & keep).sum()))
    shifts = np.linspace(-cell / 3, cell / 3, 61)
    gap = [abs(np.count_nonzero(g < c) / n_black - np.count_nonzero(g >= c) / n_white) for c in shifts]
    return float(shifts[int(np.argmin(gap))])


def checker_picture(grey: np.ndarray, cell: float, local: float, erode: float, squares: int
                    ) -> tuple[np.ndarray | None, str]:
    """The two-coloured picture of an event-line map upscaled to ~``CELL_PX`` a cell (uint8,
    grey where uncoloured; ``erode`` in cells) of a board of ``squares`` squares, or
    ``(None, reason)``: far more cells than the board has (noise, texture) is no board."""
    lines = line_mask(grey, cell, local)
    if not lines.any():
        return None, "no event lines"
    cores, n = cell_cores(lines, cell, round(erode * cell))
    if n - 1 > MAX_CELLS * squares:
        return None, f"{n - 1} cells between the lines, over {MAX_CELLS} x the board's {squares} squares"
    black, white = np.zeros(n, bool), np.zeros(n, bool)
    shift = 0.0
    for _ in range(PASSES):
        labels, f = partition(cores, black, white, shift)
        area = np.bincount(labels.ravel(), minlength=n)
        colour = two_colour(neighbours(labels, n, cell), area, max_drops=squares // 2)
        if len(colour) < 4:
            return None, "the event lines enclose no two-colourable grid of cells"
        cells = np.array(list(colour))
        outside = int(cells[np.argmax(area[cells])])  # the room or the margin around the squares: white
        is_white = np.array([colour[c] == colour[outside] for c in cells])
        new_black, new_white = np.zeros(n, bool), np.zeros(n, bool)
        new_black[cells[~is_white]], new_white[cells[is_white]] = True, True
        if np.array_equal(new_black, black) and np.array_equal(new_white, white):
            break
        black, white = new_black, new_white
        labels, f = partition(cores, black, white, 0.0)
        area = np.bincount(labels.ravel(), minlength=n)
        skip = touching_border(labels, n) | (area > 2 * cell**2)  # the room, the margin, merged cells
        shift = balance(labels, f, black, white, skip, cell)
    else:  # no pass settled: split once more at the last balance (a settled pass already did)
        labels, f = partition(cores, black, white, shift)
    inside = (black | white)[labels]
    picture = np.full(labels.shape, 128.0, np.float32)
    picture[inside] = 255.0 * np.clip(0.5 + f[inside] / (2 * BLUR_CELLS * cell), 0, 1)
    return picture.astype(np.uint8), ""
