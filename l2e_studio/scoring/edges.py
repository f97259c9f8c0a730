"""Structure, not regions: lidar edges against image edges (after Levinson and Thrun, RSS 2013).

MI of lidar intensity against a camera's grey values is dominated by large regions (sky, road,
shadow), so on real street images its peak sits degrees from the truth. What pins the geometry
is where things *change*: depth discontinuities and reflectivity steps in the scan, and
brightness edges in the image. This module holds both sides of that score:

* :func:`lidar_edge_weights`: per point, how strongly it sits on a foreground depth edge or an
  intensity step, or whether it is a silhouette against missing returns (the sky; stop 43: on
  the synthetic OS1-128, whose upper beams see sky, the truth went from 7 to 19 deviations above
  the far field), measured against its nearest horizontal neighbour on either side in the scan
  (neighbours found by direction with a k-d tree, so any scan pattern works: spinning, MEMS,
  cropped or unordered). A slope is no edge: a wall seen at a grazing angle changes range
  steadily along the ring (on 16-beam scans the earlier "largest jump to any of 12 neighbours"
  marked 77-88 % of all points as edges). Vertical neighbours are left out: rings sit up to
  2 deg apart, so a horizontal edge is located only to within that, and adding them (in inverse
  range, which cancels the ground's steady change between rings) let poses 0.5 deg off the
  reference outscore it on two of the four single-scene rigs.
* :func:`edge_map`: the image's gradient magnitude (or, opted into, its gradient across the
  lidar's scan lines: the only edges a scan that compares horizontal neighbours can match),
  normalised by its 99th percentile (contrast does not matter, saturated sky has no gradient),
  smoothed at the stage's sigma and **band-passed** (its local mean removed), so that a textured region (foliage, gravel) scores
  about zero wherever points land on it and only edges that line up precisely count.

The score is the weighted mean of the band-passed edge map under the projected edge points; a
point that leaves the image reads zero, so the score cannot grow by losing points.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

#: Neighbours (by direction) compared with each point.
NEIGHBOURS = 12
#: A neighbour is "horizontal" when its elevation differs by less than this share of its azimuth offset.
HORIZONTAL = 0.5
#: A depth jump of ``DEPTH_JUMP_M + DEPTH_JUMP_REL * range`` gives full weight.
DEPTH_JUMP_M = 0.2
DEPTH_JUMP_REL = 0.02
#: A point is a silhouette against no return (sky, beyond the lidar's range, a surface too dark or
#: glossy to return) when its nearest horizontal neighbour on one side lies at least this many times
#: further than on the other: a gap of two or more missing returns (one lone dropout is not an edge) ...
GAP_STEPS = 2.5
#: ... where the other side's neighbour sits at the scan's own step (at most this many times the
#: scan's median step: an isolated point is no silhouette) ...
GAP_NEAR = 2.0
#: ... and the gap's side, this far (deg) past the point, lies within the scan's azimuths: a cloud cut
#: to a sector (a camera's view, a lidar of limited field) leaves an empty arc wider than
#: ``GAP_OUTSIDE_DEG`` (no sky gap spans that much at every elevation), and its ends are no silhouettes.
GAP_COVER_DEG = 2.0
GAP_OUTSIDE_DEG = 90.0
#: Returns whose directions lie within this angle (deg) of each other are one sample of the scene:
#: sweeps of a static lidar accumulated into one cloud (a phase-locked lidar fires at the same
#: azimuths every sweep), or a multi-return lidar's returns of one beam. Finer than any spinning
#: lidar's own step (0.08 deg and up). Without it the neighbours a point is compared with were its
#: own copies: KITTI odometry's scans, each three times over (range noise 2 cm), calibrated
#: 0.23-3.3 deg from the reference instead of 0.02 (stop 44).
SAME_DIRECTION_DEG = 0.02
#: ... where at least this share of the returns repeats a direction: a single sweep has a few
#: beams that nearly coincide (tens in a KITTI or OpenCalib scan of 20-125k points), which are no
#: accumulation and are weighed as they are.
REPEATED_SHARE = 0.01
#: A silhouette's weight (a full depth edge's is 1). Half: silhouettes are mostly far (a skyline), which
#: pins the rotation and not the translation; at full weight KITTI odometry's halves climbed back
#: along the forward axis to 1.6 cm instead of 0.7 (its translation no longer trusted), at half weight
#: to 0.6 cm, while the synthetic OS1-128's truth still stands 19 deviations above its far field (7
#: without silhouettes, 27 at full weight; benchmarks/results/realdata.md, stop 43).
SILHOUETTE_WEIGHT = 0.5
#: An intensity step of this many grey levels (of 255, scaled to the scan's own 5-95 % spread) gives full weight.
INTENSITY_STEP = 60.0
#: Points lighter than this are no edge at all (and are left out of the objective).
MIN_WEIGHT = 0.05
#: The band-pass removes a local mean this many times wider than the stage's smoothing.
BANDPASS = 4.0
#: Stored edge maps: value = OFFSET + SCALE * band-passed edge (0..255, OFFSET meaning "no edge").
OFFSET = 128.0
SCALE = 127.0


def lidar_edge_weights(points: np.ndarray, intensity: np.ndarray) -> np.ndarray:
    """(N,) weights in [0, 1] (:func:`sample_edge_weights`), one sample per direction: where a
    cloud repeats directions (:data:`REPEATED_SHARE`), returns within :data:`SAME_DIRECTION_DEG`
    of one another are one sample, whose nearest return is weighed; the others take its weight
    where they lie on its surface (within a depth edge's jump of it: an accumulated sweep's
    copy), else none (a later return from a surface behind, which the camera sees elsewhere)."""
    P = np.asarray(points, dtype=np.float64)
    r, ok, d = _directions(P)
    tree = cKDTree(d)
    pairs = tree.query_pairs(2 * np.sin(np.radians(SAME_DIRECTION_DEG) / 2), output_type="ndarray")
    pairs = pairs[ok[pairs].all(axis=1)]  # (points without a direction all sit at the origin)
    if len(np.unique(pairs)) < REPEATED_SHARE * ok.sum():
        return sample_edge_weights(P, intensity, (r, ok, d, tree))
    n = len(P)
    _, label = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)),
                                    directed=False)
    order = np.lexsort((r, label))  # by sample, nearest return first
    first = np.ones(n, dtype=bool)
    first[1:] = label[order][1:] != label[order][:-1]
    nearest = order[first]  # one return per sample, the nearest
    rep = np.empty(n, dtype=np.int64)
    rep[order] = np.repeat(nearest, np.diff(np.r_[np.flatnonzero(first), n]))
    w = np.zeros(n, dtype=np.float32)
    w[nearest] = sample_edge_weights(P[nearest], np.asarray(intensity)[nearest])
    same = r - r[rep] <= DEPTH_JUMP_M + DEPTH_JUMP_REL * r[rep]
    return np.where(same & ok, w[rep], 0.0).astype(np.float32)


def _directions(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point's range, whether it has a direction, and its unit direction (zero where none)."""
    r = np.linalg.norm(P, axis=1)
    ok = np.isfinite(r) & (r > 1e-6)
    d = np.zeros_like(P)
    d[ok] = P[ok] / r[ok, None]
    return r, ok, d


def sample_edge_weights(points: np.ndarray, intensity: np.ndarray, prepared: tuple | None = None) -> np.ndarray:
    """(N,) weights in [0, 1]: the larger of a point's foreground depth discontinuity and
    intensity step against its nearest horizontal neighbours on either side (lidar frame, z up;
    one return per direction).

    Only the nearest neighbour to the left and to the right count, and a slope is not an edge:
    a surface seen at a grazing angle (a wall along the street, the ground at range) changes
    range steadily from one point to the next, which the far side's change cancels. A point is
    a depth edge when it is in front of one side (occlusion: only the foreground point, which
    the camera sees at the boundary) without the other side falling away as much; a thin pole
    in front of both sides is an edge too. A point beside a gap in the scan, where no return came
    back (sky, a surface beyond the range or too dark), is a silhouette (:data:`SILHOUETTE_WEIGHT`): an
    object against the sky has no farther neighbour to jump to, and those are the edges an
    upward-looking lidar sees most of (:data:`GAP_STEPS`). Intensity steps are measured between the means of
    the two nearest points on either side and scaled to the scan's own spread and neighbour
    noise (sensors report 0..1, 0..100 or 0..255, with very different noise). ``prepared``:
    :func:`_directions` of the points and a k-d tree of the directions, when made already.
    """
    P = np.asarray(points, dtype=np.float64)
    n = len(P)
    if n < NEIGHBOURS + 1:
        return np.zeros(n, dtype=np.float32)
    r, ok, d, tree = prepared or (*_directions(P), None)
    az = np.arctan2(P[:, 1], P[:, 0])
    el = np.arcsin(np.clip(d[:, 2], -1.0, 1.0))
    _, nb = (cKDTree(d) if tree is None else tree).query(d, k=NEIGHBOURS + 1, workers=-1)
    nb = np.minimum(nb[:, 1:], n - 1)
    signed = np.angle(np.exp(1j * (az[nb] - az[:, None])))
    daz = np.abs(signed)
    horizontal = (np.abs(el[nb] - el[:, None]) < HORIZONTAL * daz) & (daz > 0)
    rows = np.arange(n)[:, None]

    def nearest(side: np.ndarray, rank: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Index of each point's ``rank``-th nearest neighbour on ``side``, whether it exists, and
        its azimuth offset (inf where none)."""
        key = np.where(side, daz, np.inf)
        order = np.argsort(key, axis=1)[:, rank]
        offset = key[rows[:, 0], order]
        return nb[rows[:, 0], order], np.isfinite(offset), offset

    left, right = horizontal & (signed < 0), horizontal & (signed > 0)
    l1, has_l, gap_l = nearest(left, 0)
    r1, has_r, gap_r = nearest(right, 0)
    both = has_l & has_r
    dl, dr = r[l1] - r, r[r1] - r
    jump = np.maximum(dl, dr) - np.maximum(0.0, -np.minimum(dl, dr))
    jump = np.where(both, jump, 0.0)
    w_depth = np.clip(jump / (DEPTH_JUMP_M + DEPTH_JUMP_REL * r), 0.0, 1.0)
    edge = silhouettes(np.where(ok, az, np.nan), gap_l, gap_r)
    w_depth[edge] = np.maximum(w_depth[edge], SILHOUETTE_WEIGHT)

    inten = np.asarray(intensity, dtype=np.float64)
    l2, has_l2, _ = nearest(left, 1)
    r2, has_r2, _ = nearest(right, 1)
    four = both & has_l2 & has_r2
    step = np.abs(inten[l1] + inten[l2] - inten[r1] - inten[r2]) / 2.0
    pair = np.abs(inten[r1] - inten)[has_r]
    noise = 1.4826 * float(np.median(pair)) if pair.size else 0.0  # spread of one neighbour's difference
    lo, hi = np.percentile(inten[ok], [5, 95]) if ok.any() else (0.0, 0.0)
    full = max(INTENSITY_STEP * (hi - lo) / 255.0, 4.0 * noise, 1e-9)
    w_int = np.where(four, np.clip((step - noise) / full, 0.0, 1.0), 0.0)
    w = np.maximum(w_depth, w_int)
    w[~ok] = 0.0
    return w.astype(np.float32)


def silhouettes(az: np.ndarray, gap_l: np.ndarray, gap_r: np.ndarray) -> np.ndarray:
    """(N,) bool: points beside a gap of missing returns along the scan (:data:`GAP_STEPS`), given
    each point's azimuth (rad; nan for a point without a direction) and the azimuth offsets of its
    nearest horizontal neighbours to the left and right (inf where none)."""
    near, far = np.minimum(gap_l, gap_r), np.maximum(gap_l, gap_r)
    steps = near[np.isfinite(near)]
    if steps.size == 0:
        return np.zeros(az.shape, dtype=bool)
    step = float(np.median(steps))
    # the gap against the scan's own spacing too, the larger neighbour offset's median: sweeps
    # accumulated at azimuths of their own sample a ring irregularly, a point's neighbours a
    # fraction of a step away on one side and most of one on the other (the ratio alone read
    # 60-65 % of such a cloud's points as silhouettes); on a single sweep it is the scan's step
    fars = far[np.isfinite(far)]
    spacing = float(np.median(fars)) if fars.size else step
    aimed = np.isfinite(az)
    gap = aimed & np.isfinite(near) & (near <= GAP_NEAR * step) & (far > GAP_STEPS * np.maximum(near, spacing))
    side = np.where(gap_l > gap_r, -1.0, 1.0)
    past = _degree_bins(np.where(gap, az, 0.0) + side * np.radians(GAP_COVER_DEG))
    return gap & ~outside_arc(az[aimed])[past]


def _degree_bins(az: np.ndarray) -> np.ndarray:
    """Each azimuth's (rad) 1 deg bin, 0..359."""
    return np.floor(np.degrees(az) % 360.0).astype(np.int64) % 360


def outside_arc(az: np.ndarray) -> np.ndarray:
    """(360,) bool per 1 deg of azimuth: the widest arc without a point, where wider than
    :data:`GAP_OUTSIDE_DEG` (outside a cloud cut to a sector); all False for a scan all round."""
    empty = np.bincount(_degree_bins(az), minlength=360) == 0
    out = np.zeros(360, dtype=bool)
    if empty.all() or not empty.any():
        return out
    start = int(np.argmin(empty))  # an occupied bin: runs of empty bins after it do not wrap
    ring = np.roll(empty, -start)
    bounds = np.flatnonzero(np.diff(np.r_[0, ring.astype(np.int8), 0]))
    runs = bounds.reshape(-1, 2)  # [first, last + 1) of each empty run
    first, stop = max(runs, key=lambda ab: ab[1] - ab[0])
    if stop - first > GAP_OUTSIDE_DEG:
        out[(np.arange(first, stop) + start) % 360] = True
    return out


#: How much an angle along a scan line counts against one across it when looking for the
#: neighbours above and below a point: a spinning lidar's next point along its line (0.1-0.4 deg)
#: then sits further off than the next line (0.3-2 deg).
ALONG_WEIGHT = 20.0


def scan_line_spacing_deg(points: np.ndarray) -> float:
    """How far apart (deg) the lidar's scan lines are: the median, over the points, of the elevation
    to the nearest point of the line above or below (lidar frame, z up); nan without such pairs.

    The edge score finds its lidar edges along the scan lines only, so an edge that runs along
    them is placed no finer than this (2.0 on a VLP-16, 0.34-0.36 on the OpenCalib and KITTI dev rigs).
    Pass the points in the camera's view: there the lines' spacing is what the image sees, and a
    lens 90 deg wide keeps the azimuths off their wrap-around (they are centred on their mean)."""
    P = np.asarray(points, dtype=np.float64)
    r = np.linalg.norm(P, axis=1)
    ok = np.isfinite(r) & (r > 1e-6)
    P, r = P[ok], r[ok]
    if len(P) < 4:
        return float("nan")
    az = np.arctan2(P[:, 1], P[:, 0])
    az = np.degrees(np.angle(np.exp(1j * (az - np.angle(np.exp(1j * az).mean())))))
    el = np.degrees(np.arcsin(np.clip(P[:, 2] / r, -1.0, 1.0)))
    flat = np.c_[ALONG_WEIGHT * az, el]
    _, nb = cKDTree(flat).query(flat, k=4, workers=-1)
    de, da = np.abs(el[nb[:, 1:]] - el[:, None]), np.abs(az[nb[:, 1:]] - az[:, None])
    across = np.where(de > 2.0 * da, de, np.inf).min(axis=1)  # the nearest of the lines above and below
    across = across[np.isfinite(across)]
    return float(np.median(across)) if across.size else float("nan")


def magnitude(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """``sqrt(gx² + gy²)``, the same to the bit wherever the arrays sit in memory (OpenCV's
    ``magnitude`` is not: its vector and scalar paths differ in the last bit, so one map
    prepared twice could differ, and with it an optimiser's path)."""
    return np.sqrt(gx * gx + gy * gy)


def sobel(image: np.ndarray, blur: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """d/du and d/dv of the image after a ``blur`` px Gaussian blur."""
    g = cv2.GaussianBlur(np.asarray(image, dtype=np.float32), (0, 0), blur)
    return cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)


def unit_p99(m: np.ndarray) -> np.ndarray:
    """``m`` scaled so its 99th percentile is 1, clipped there (contrast does not matter)."""
    p99 = float(np.percentile(m, 99))
    if p99 <= 0:
        return np.zeros_like(m)
    return np.minimum(m / p99, 1.0)


def gradient_magnitude(image: np.ndarray) -> np.ndarray:
    """Sobel gradient magnitude of a lightly blurred image, scaled so its 99th percentile is 1
    (every orientation: what the structure check's Canny edges see)."""
    return unit_p99(magnitude(*sobel(image)))


def scan_gradient(image: np.ndarray, scan: np.ndarray) -> np.ndarray:
    """The image gradient along the lidar's scan lines, ``|grad . u|``, scaled so its 99th
    percentile is 1; ``scan`` is the (H, W, 2) unit direction ``u`` of the scan lines at every
    pixel (:func:`l2e_studio.score_maps.scan_directions`).

    The lidar side finds its edges between neighbours along a scan line only, so the image
    edges it can line up with are those that cut across the scan lines; an edge that runs along
    them (a horizon, a kerb, a shelf) is clutter the scan can never match and a pull on the
    score toward wherever the rings happen to sit. Kept out, the sparse 16-beam rigs (rings a
    degree or more apart) peak near their reference instead of degrees off it.
    """
    gx, gy = sobel(image)
    return unit_p99(np.abs(gx * scan[..., 0] + gy * scan[..., 1]))


def edge_map(
    image: np.ndarray, sigma: float, size: tuple[int, int] | None = None, scan: np.ndarray | None = None
) -> np.ndarray:
    """The map the edge score reads: the gradient magnitude, or with a ``scan`` field (at the
    image's full resolution) the gradient across the scan lines (:func:`scan_gradient`);
    optionally resized to ``size`` (w, h), smoothed with ``sigma`` (pixels of the output) and
    band-passed, stored as ``OFFSET + SCALE * value`` in float32 (so that 0..255 holds it,
    OFFSET meaning no edge)."""
    m = gradient_magnitude(image) if scan is None else scan_gradient(image, scan)
    if size is not None and size != (m.shape[1], m.shape[0]):
        m = cv2.resize(m, size, interpolation=cv2.INTER_AREA)
    s = max(float(sigma), 0.5)
    m = cv2.GaussianBlur(m, (0, 0), s, borderType=cv2.BORDER_REFLECT)
    m = m - cv2.GaussianBlur(m, (0, 0), BANDPASS * s, borderType=cv2.BORDER_REFLECT)
    return (OFFSET + SCALE * np.clip(m, -1.0, 1.0)).astype(np.float32)


def canny_distance(image: np.ndarray) -> np.ndarray:
    """Distance (px) from each pixel to the nearest Canny edge of the image (thresholds from the
    gradient's own percentiles, so they follow the image's contrast)."""
    g = cv2.GaussianBlur(np.asarray(image, dtype=np.float32), (0, 0), 1.5)
    g8 = cv2.normalize(g, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    grad = magnitude(cv2.Sobel(g8, cv2.CV_32F, 1, 0), cv2.Sobel(g8, cv2.CV_32F, 0, 1))
    hi = float(np.percentile(grad, 90))
    edges = cv2.Canny(g8, 0.5 * hi, hi, L2gradient=True)
    if not edges.any():
        return np.full(g.shape, np.inf, dtype=np.float32)
    return cv2.distanceTransform(255 - edges, cv2.DIST_L2, 3)
