"""The engine's per-point and per-pixel loops, compiled (numba): the nearest pixel of each
projected lidar point, the (L, E) pair counts the paper's MI is made of, the maps' E bins, the
bilinear lookup (with its derivatives) the optimiser's smooth objectives read the maps with, the
soft histogram and the separable smoothing of the smooth MI, and the per-event count of a raw
recording's window into its event map.

The reported MI reads every point of every scene at every evaluation (3M points for 40 scenes),
and the workbench's readout does it on each key press. As numpy expressions, projection with
lens distortion is some twenty passes over the points, each a temporary the size of the cloud;
one fused loop keeps each point in registers and lets the compiler vectorise it (only where no
branch is left in it: the pixel index's test of the lens's fold as a branch kept it scalar). The
pixel index of 3M points on one core of this host (AMD EPYC): 12-15 ms for a pinhole or radtan
lens, 50-56 ms for a fisheye (its arctan stays scalar), 30-105 ms with that branch. The bilinear
lookup reads the float32 maps where numpy needed a packed copy of 40 full-size maps (300 MB,
0.4-0.8 s per stage).

The smooth objectives' evaluation (:class:`Lookup`) is three loops per chunk of points: the
projection (vectorised; one loop per lens model, a branch on the model inside kept it scalar, 6x
slower), the gather from the maps (scalar and memory-bound: a 400k-point evaluation at full size
touches 800k cache lines of 150 MB of maps), and for the gradient the projection again with the
lens's Jacobian, summing the weighted derivatives (cheaper than writing and reading back a 6 x N
Jacobian). On 40 full-size scenes a final-stage value and gradient went from 49 ms (numpy
projection, compiled gather) to 14-19 ms, the 40-scene optimisation with its verdict from 3.95 s
to 2.9-3.2 s (``benchmarks/bench_engine.py``, 2 cores).

Semantics match :func:`l2e_studio.geometry.project_points` and ``in_image``: the camera frame is
``R p + t``; points with depth <= ``min_depth``, beyond the lens's fold (``CameraModel.max_r2``) or outside ``[-0.5, W - 0.5) x [-0.5, H - 0.5)``
get -1 (the far border is exclusive, so that rounding stays inside); the rest get
``row * W + col`` of the nearest pixel. The arithmetic is float32, as the stacked points are: a
point within ~1e-4 px of a pixel border may round the other way than in float64.
"""

from __future__ import annotations

import os

import numpy as np

from .cachedir import user_cache_dir

# numba reads this when it is imported: compiled kernels are cached in the user's cache folder,
# not beside the installed package (which may not be writable)
os.environ.setdefault("NUMBA_CACHE_DIR", str(user_cache_dir("numba")))

import numba  # noqa: E402

from .camera import CameraModel  # noqa: E402

# Everything but "no NaN / no inf": far outside the lens's field of view the distortion
# polynomial overflows, and those points must still compare as outside the image.
_FAST = {"contract", "arcp", "afn", "reassoc", "nsz"}
_JIT = dict(nogil=True, cache=True, fastmath=_FAST, boundscheck=False, error_model="numpy")


@numba.njit(inline="always", **_JIT)
def _camera_xyz(px, py, pz, i, R, t):
    X, Y, Z = px[i], py[i], pz[i]
    return (R[0, 0] * X + R[0, 1] * Y + R[0, 2] * Z + t[0],
            R[1, 0] * X + R[1, 1] * Y + R[1, 2] * Z + t[1],
            R[2, 0] * X + R[2, 1] * Y + R[2, 2] * Z + t[2])


@numba.njit(inline="always", **_JIT)
def _radtan(x, y, D):
    k1, k2, p1, p2, k3, k4, k5, k6 = D[0], D[1], D[2], D[3], D[4], D[5], D[6], D[7]
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xy = x * y
    return (x * radial + 2 * p1 * xy + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * xy)


@numba.njit(inline="always", **_JIT)
def _fisheye_angle(x, y, D):
    """The equidistant model's radius r, squared angle th^2 and distorted angle th_d."""
    r = np.sqrt(x * x + y * y)
    th = np.arctan(r)
    th2 = th * th
    return r, th2, th * (1 + th2 * (D[0] + th2 * (D[1] + th2 * (D[2] + th2 * D[3]))))


@numba.njit(inline="always", **_JIT)
def _equidistant(x, y, D):
    r, _, thd = _fisheye_angle(x, y, D)
    scale = thd / r if r >= 1e-8 else np.float32(1.0)
    return x * scale, y * scale


@numba.njit(inline="always", **_JIT)
def _pixel(xd, yd, z, r2, K, W, H, min_depth, r2max):
    # every test in one mask, no branch: the loops calling this vectorise (a branch on the lens's
    # fold around it kept them scalar, 4x slower)
    u = K[0] * xd + K[2] * yd + K[3]
    v = K[1] * yd + K[4]
    ok = (z > min_depth) & (r2 <= r2max) & (u >= -0.5) & (u < W - 0.5) & (v >= -0.5) & (v < H - 0.5)
    uu = u + 0.5 if ok else np.float32(0.5)
    vv = v + 0.5 if ok else np.float32(0.5)
    pix = np.int32(vv) * np.int32(W) + np.int32(uu)
    return pix if ok else np.int32(-1)


@numba.njit(**_JIT)
def _index_radtan(px, py, pz, R, t, K, D, W, H, min_depth, r2max, out):
    for i in range(px.size):
        xc, yc, zc = _camera_xyz(px, py, pz, i, R, t)
        x, y = xc / zc, yc / zc
        xd, yd = _radtan(x, y, D)
        out[i] = _pixel(xd, yd, zc, x * x + y * y, K, W, H, min_depth, r2max)


@numba.njit(**_JIT)
def _index_equidistant(px, py, pz, R, t, K, D, W, H, min_depth, r2max, out):
    for i in range(px.size):
        xc, yc, zc = _camera_xyz(px, py, pz, i, R, t)
        x, y = xc / zc, yc / zc
        xd, yd = _equidistant(x, y, D)
        out[i] = _pixel(xd, yd, zc, x * x + y * y, K, W, H, min_depth, r2max)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _count_pairs(pix, l_bins, e_bins, hist):
    for i in range(pix.size):
        p = pix[i]
        if p >= 0:
            hist[l_bins[i] * 256 + e_bins[p]] += 1


@numba.njit(nogil=True, cache=True, boundscheck=False)  # (no fastmath: the sum is numpy's bincount's, bit for bit)
def _edge_sum(pix, weights, m, offset, scale):
    W = m.shape[1] - 2
    acc = 0.0
    for i in range(pix.size):
        p = pix[i]
        e = m[p // W + 1, p % W + 1] if p >= 0 else m[0, 0]  # off the image: the border
        acc += np.float64(weights[i]) * (np.float64(e) - offset) / scale
    return acc


def _lens(camera: CameraModel, shift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The camera's intrinsics (fx, fy, skew, cx + shift, cy + shift) and its 8 distortion
    coefficients, float32."""
    K = camera.K
    K = np.array([K[0, 0], K[1, 1], K[0, 1], K[0, 2] + shift, K[1, 2] + shift], np.float32)
    D = np.zeros(8, np.float32)
    D[: camera.D.size] = camera.D
    return K, D


def pixel_index(
    points: np.ndarray, R: np.ndarray, t: np.ndarray, camera: CameraModel, min_depth: float,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """(N,) int32 flat index ``row * W + col`` of the pixel nearest each of the (3, N) float32
    lidar points at ``R p + t``, or -1 for a point behind ``min_depth``, beyond the lens's fold or off the image."""
    pts = np.asarray(points, dtype=np.float32)
    n = pts.shape[1]
    out = np.empty(n, np.int32) if out is None else out[:n]
    K, D = _lens(camera)
    kernel = _index_equidistant if camera.model == "equidistant" else _index_radtan
    kernel(pts[0], pts[1], pts[2], np.asarray(R, np.float32), np.asarray(t, np.float32), K, D,
           camera.width, camera.height, np.float32(min_depth), np.float32(camera.max_r2), out)
    return out


def edge_sum(pix: np.ndarray, weights: np.ndarray, padded_map: np.ndarray, offset: float, scale: float) -> float:
    """The sum over points of ``weight * (e - offset) / scale``, ``e`` the (H+2, W+2) zero-bordered
    map at each point's pixel ``pix`` (its border where -1, off the image), in float64 in the
    points' order: what ``np.bincount`` with these weights sums, to the last bit."""
    return float(_edge_sum(pix, weights, padded_map, float(offset), float(scale)))


@numba.njit(inline="always", nogil=True, boundscheck=False)
def _poses_loop(index, xyz, lens, starts, Rs, ts, l_bins, e_bins, hists, weights, maps, offset, scale, sums, pix):
    px, py, pz = xyz
    K, D, W, H, min_depth, r2max = lens
    for s in range(starts.size - 1):  # scene by scene: its map stays in cache while every pose reads it
        a, b = starts[s], starts[s + 1]
        for k in range(Rs.shape[0]):
            index(px[a:b], py[a:b], pz[a:b], Rs[k], ts[k], K, D, W, H, min_depth, r2max, pix[:b - a])
            if hists.shape[0]:  # the MI's pair counts, else the edge score's sums
                _count_pairs(pix[:b - a], l_bins[a:b], e_bins[s], hists[k])
            else:
                sums[k, s] = _edge_sum(pix[:b - a], weights[a:b], maps[s], offset, scale)


# one per lens model, chosen in Python, so that only the camera's compiles
@numba.njit(nogil=True, cache=True, boundscheck=False)
def _poses_radtan(xyz, lens, starts, Rs, ts, l_bins, e_bins, hists, weights, maps, offset, scale, sums, pix):
    _poses_loop(_index_radtan, xyz, lens, starts, Rs, ts, l_bins, e_bins, hists, weights, maps, offset, scale, sums, pix)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _poses_equidistant(xyz, lens, starts, Rs, ts, l_bins, e_bins, hists, weights, maps, offset, scale, sums, pix):
    _poses_loop(_index_equidistant, xyz, lens, starts, Rs, ts, l_bins, e_bins, hists, weights, maps, offset, scale,
                sums, pix)


#: what the per-pose kernel is given for the half of its work not asked for (zero-length, typed alike)
_NO_PAIRS = (np.zeros(0, np.int32), np.zeros((0, 1), np.uint8), np.zeros((0, 65536), np.int32))
_NO_SUMS = (np.zeros(0, np.float32), np.zeros((0, 3, 3), np.float32), 0.0, 1.0, np.zeros((0, 0)))


def _at_poses(points: np.ndarray, starts: np.ndarray, Rs: np.ndarray, ts: np.ndarray, camera: CameraModel,
              min_depth: float, pairs: tuple, sums: tuple) -> None:
    """:func:`count_pairs_at_poses` (``pairs``: l_bins, e_bins, hists) or :func:`edge_sums_at_poses`
    (``sums``: weights, maps, offset, scale, sums), the other ``_NO_*``: one kernel per lens model."""
    K, D = _lens(camera)
    lens = (K, D, camera.width, camera.height, np.float32(min_depth), np.float32(camera.max_r2))
    kernel = _poses_equidistant if camera.model == "equidistant" else _poses_radtan
    weights, maps, offset, scale, out = sums
    kernel((points[0], points[1], points[2]), lens, starts.astype(np.int64), np.ascontiguousarray(Rs, np.float32),
           np.ascontiguousarray(ts, np.float32), *pairs, weights, maps, float(offset), float(scale), out,
           np.empty(int(np.diff(starts).max(initial=0)), np.int32))


def count_pairs_at_poses(points: np.ndarray, l_bins: np.ndarray, starts: np.ndarray, Rs: np.ndarray, ts: np.ndarray,
                         camera: CameraModel, min_depth: float, e_bins: np.ndarray, hists: np.ndarray) -> None:
    """Add to ``hists[k]`` (65536 int32) the (L, E) pairs of every scene at pose ``Rs[k], ts[k]``:
    :func:`pixel_index` and :func:`count_pairs` of each scene (points ``starts[s]:starts[s + 1]``
    of the (3, N) float32 ``points``, map bins ``e_bins[s]``) at each pose, the same counts, taken
    scene by scene across all poses so that a scene's map is read from cache by every pose."""
    _at_poses(points, starts, Rs, ts, camera, min_depth, (l_bins, e_bins, hists), _NO_SUMS)


def edge_sums_at_poses(points: np.ndarray, weights: np.ndarray, starts: np.ndarray, Rs: np.ndarray, ts: np.ndarray,
                       camera: CameraModel, min_depth: float, maps: np.ndarray, offset: float, scale: float,
                       sums: np.ndarray) -> None:
    """``sums[k, s]``: :func:`edge_sum` of scene ``s``'s points (``starts[s]:starts[s + 1]``) at
    pose ``Rs[k], ts[k]`` on its map ``maps[s]`` (S, H+2, W+2), scene by scene across all poses as
    :func:`count_pairs_at_poses`."""
    _at_poses(points, starts, Rs, ts, camera, min_depth, _NO_PAIRS, (weights, maps, offset, scale, sums))


def count_pairs(pix: np.ndarray, l_bins: np.ndarray, e_bins: np.ndarray, hist: np.ndarray) -> None:
    """Add one to ``hist[l * 256 + e]`` for each point with ``pix >= 0``, where ``l`` is its
    intensity bin and ``e = e_bins[pix]`` the map's bin at its pixel (``hist``: 65536 int32)."""
    _count_pairs(pix, l_bins, e_bins, hist)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _e_bins_scene(m, out):
    h, w = out.shape
    for y in range(h):
        for x in range(w):
            out[y, x] = np.uint8(min(max(np.rint(m[y + 1, x + 1]), 0.0), 255.0))


@numba.njit(inline="always", **_JIT)
def _radtan_jacobian(x, y, D):
    k1, k2, p1, p2, k3, k4, k5, k6 = D[0], D[1], D[2], D[3], D[4], D[5], D[6], D[7]
    r2 = x * x + y * y
    a = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    b = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
    radial = a / b
    xy = x * y
    xd = x * radial + 2 * p1 * xy + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * xy
    da = k1 + r2 * (2 * k2 + r2 * 3 * k3)
    db = k4 + r2 * (2 * k5 + r2 * 3 * k6)
    drad = (da * b - a * db) / (b * b)
    cross = 2 * xy * drad + 2 * p1 * x + 2 * p2 * y
    return (xd, yd, radial + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x, cross, cross,
            radial + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x)


@numba.njit(inline="always", **_JIT)
def _equidistant_jacobian(x, y, D):
    r, th2, thd = _fisheye_angle(x, y, D)
    if r < 1e-8:
        return x, y, np.float32(1.0), np.float32(0.0), np.float32(0.0), np.float32(1.0)
    scale = thd / r
    dthd = 1 + th2 * (3 * D[0] + th2 * (5 * D[1] + th2 * (7 * D[2] + th2 * 9 * D[3])))
    ds_r = (dthd / (1 + r * r) * r - thd) / (r * r * r)  # d(scale)/dr / r: d(scale)/dx = x ds_r
    return x * scale, y * scale, scale + x * x * ds_r, x * y * ds_r, x * y * ds_r, scale + y * y * ds_r


@numba.njit(inline="always", **_JIT)
def _camera_point(px, py, pz, i, R, t, K, D, equidistant, r2max, min_depth, jacobian):
    """Point i in the camera frame (rotated only: q0..q2), its normalised coordinates x, y and
    1 / depth, its packed-map coordinates u, v (map pixel (0, 0) at (1, 1) of the zero-padded
    map), whether the camera sees it, and with ``jacobian`` the lens's d(xd, yd)/d(x, y)."""
    q0 = R[0, 0] * px[i] + R[0, 1] * py[i] + R[0, 2] * pz[i]
    q1 = R[1, 0] * px[i] + R[1, 1] * py[i] + R[1, 2] * pz[i]
    q2 = R[2, 0] * px[i] + R[2, 1] * py[i] + R[2, 2] * pz[i]
    zc = q2 + t[2]
    inv_z = np.float32(1.0) / (zc if zc > min_depth else min_depth)
    x = (q0 + t[0]) * inv_z
    y = (q1 + t[1]) * inv_z
    front = (zc > min_depth) & (x * x + y * y <= r2max)
    one, zero = np.float32(1.0), np.float32(0.0)
    if jacobian:
        if equidistant:
            xd, yd, j00, j01, j10, j11 = _equidistant_jacobian(x, y, D)
        else:
            xd, yd, j00, j01, j10, j11 = _radtan_jacobian(x, y, D)
    else:
        xd, yd = _equidistant(x, y, D) if equidistant else _radtan(x, y, D)
        j00, j01, j10, j11 = one, zero, zero, one
    u = K[0] * xd + K[2] * yd + K[3]
    v = K[1] * yd + K[4]
    return q0, q1, q2, x, y, inv_z, u, v, front, j00, j01, j10, j11


@numba.njit(inline="always", **_JIT)
def _coordinates_of(px, py, pz, i, R, t, K, D, equidistant, r2max, min_depth, u_max, v_max, uc, vc, ku, kv):
    """Point i's clamped lookup coordinates, and whether its value has a derivative along u and v
    (1) or was clamped to the border or is not seen (0). Its loops (:func:`_coordinates_radtan`,
    :func:`_coordinates_equidistant`) vectorise, one per lens model: a branch on the model
    inside kept the loop scalar, 6x slower."""
    _, _, _, _, _, _, u, v, front, _, _, _, _ = _camera_point(px, py, pz, i, R, t, K, D, equidistant, r2max,
                                                              min_depth, False)
    a = u if u >= 0 else np.float32(0.0)  # (NaN, an overflowed projection, too)
    b = v if v >= 0 else np.float32(0.0)
    uc[i] = (a if a <= u_max else u_max) if front else np.float32(0.0)  # not seen: reads column 0
    vc[i] = b if b <= v_max else v_max
    ku[i] = np.float32(1.0) if front & (u > 0) & (u < u_max) else np.float32(0.0)
    kv[i] = np.float32(1.0) if front & (v > 0) & (v < v_max) else np.float32(0.0)


@numba.njit(**_JIT)
def _coordinates_radtan(px, py, pz, R, t, K, D, r2max, min_depth, u_max, v_max, uc, vc, ku, kv):
    for i in range(px.size):
        _coordinates_of(px, py, pz, i, R, t, K, D, False, r2max, min_depth, u_max, v_max, uc, vc, ku, kv)


@numba.njit(**_JIT)
def _coordinates_equidistant(px, py, pz, R, t, K, D, r2max, min_depth, u_max, v_max, uc, vc, ku, kv):
    for i in range(px.size):
        _coordinates_of(px, py, pz, i, R, t, K, D, True, r2max, min_depth, u_max, v_max, uc, vc, ku, kv)


@numba.njit(inline="always", **_JIT)
def _bilinear_at(maps, base, row, u, v):
    iu = np.int64(u)  # u, v >= 0: truncation is the floor
    iv = np.int64(v)
    fu = u - np.float32(iu)
    fv = v - np.float32(iv)
    k = base + iv * row + iu
    m00, m01, m10, m11 = maps[k], maps[k + 1], maps[k + row], maps[k + row + 1]
    top = m00 + fu * (m01 - m00)
    bot = m10 + fu * (m11 - m10)
    return top + fv * (bot - top), (m01 - m00) + fv * ((m11 - m10) - (m01 - m00)), bot - top


@numba.njit(**_JIT)
def _gather(maps, base, row, uc, vc, ku, kv, e_max, e, de_du, de_dv, derivatives):
    for i in range(uc.size):
        value, du, dv = _bilinear_at(maps, base[i], row, uc[i], vc[i])
        e[i] = value if value < e_max else e_max
        if derivatives:
            de_du[i] = ku[i] * du
            de_dv[i] = kv[i] * dv


@numba.njit(inline="always", **_JIT)
def _weighted_derivatives(px, py, pz, R, t, K, D, equidistant, r2max, min_depth, w, de_du, de_dv):
    """Sum over the points of d(u, v)/d(dt, dw) weighted by w (de/du, de/dv)."""
    g0 = g1 = g2 = g3 = g4 = g5 = 0.0
    for i in range(px.size):
        q0, q1, q2, x, y, inv_z, _, _, _, j00, j01, j10, j11 = _camera_point(px, py, pz, i, R, t, K, D, equidistant,
                                                                             r2max, min_depth, True)
        # chain through d(u, v)/d(x, y) and d(x, y)/d(X, Y, Z)
        wu, wv = w[i] * de_du[i], w[i] * de_dv[i]
        gx = wu * (K[0] * j00 + K[2] * j10) + wv * (K[1] * j10)
        gy = wu * (K[0] * j01 + K[2] * j11) + wv * (K[1] * j11)
        gX = gx * inv_z
        gY = gy * inv_z
        gZ = -(gx * x + gy * y) * inv_z
        g0 += gX
        g1 += gY
        g2 += gZ
        # rotation: d X_cam / d dw = -[Q]x J_l(dw), so de/d(dw) = J_l^T (Q x g)
        g3 += q1 * gZ - q2 * gY
        g4 += q2 * gX - q0 * gZ
        g5 += q0 * gY - q1 * gX
    return g0, g1, g2, g3, g4, g5


@numba.njit(**_JIT)
def _gradient_radtan(px, py, pz, R, t, K, D, r2max, min_depth, w, de_du, de_dv, out):
    g = _weighted_derivatives(px, py, pz, R, t, K, D, False, r2max, min_depth, w, de_du, de_dv)
    out[0], out[1], out[2], out[3], out[4], out[5] = g


@numba.njit(**_JIT)
def _gradient_equidistant(px, py, pz, R, t, K, D, r2max, min_depth, w, de_du, de_dv, out):
    g = _weighted_derivatives(px, py, pz, R, t, K, D, True, r2max, min_depth, w, de_du, de_dv)
    out[0], out[1], out[2], out[3], out[4], out[5] = g


class Lookup:
    """The smooth objectives' per-point work on a chunk of lidar points, each pass one compiled
    loop or two: the points projected at ``R p + t`` (lens distortion included) and the float32
    maps read there bilinearly, with the lookup's derivatives along u and v (:meth:`values`);
    the derivatives' sum, weighted, with respect to a correction ``(dt, dw)`` of the extrinsic
    (:meth:`gradient`: the projection again, which costs less than writing a 6 x N Jacobian).
    The projecting loops are compiled per lens model, and only the camera's model is (on first
    use: compiling both took 4.6 s on this project's machine, once per machine).

    ``maps``: the flat zero-padded maps, scene s's pixel (x, y) at ``scene_base + (y + 1) * row
    + x + 1``; coordinates are clamped to ``u_max``, ``v_max`` so the neighbour at +1 exists. A
    point behind ``min_depth`` or past the lens's fold reads column 0 and has no derivative, nor
    has a point clamped to the border along the clamped coordinate."""

    def __init__(self, camera: CameraModel, maps: np.ndarray, scene_base: np.ndarray, row: int,
                 u_max: float, v_max: float, min_depth: float, e_max: float) -> None:
        self._K, self._D = _lens(camera, 1.0)  # (+1: the one-pixel padding)
        equidistant = camera.model == "equidistant"
        self._coordinates = _coordinates_equidistant if equidistant else _coordinates_radtan
        self._gradient = _gradient_equidistant if equidistant else _gradient_radtan
        self._r2max = np.float32(camera.max_r2)
        self._maps, self._base, self._row = maps, scene_base, np.int64(row)
        self._u_max, self._v_max = np.float32(u_max), np.float32(v_max)
        self._min_depth, self._e_max = np.float32(min_depth), np.float32(e_max)

    def values(self, points: np.ndarray, a: int, b: int, R: np.ndarray, t: np.ndarray, e: np.ndarray,
               de_du: np.ndarray | None = None, de_dv: np.ndarray | None = None) -> None:
        """Fill ``e[a:b]`` with the map values (at most ``e_max``) at points ``a:b`` of the (3, N)
        float32 ``points`` at the float32 ``R``, ``t``, and, when given, ``de_du[a:b]`` and
        ``de_dv[a:b]`` with the lookup's derivatives."""
        derivatives = de_du is not None and de_dv is not None
        du, dv = (de_du[a:b], de_dv[a:b]) if derivatives else (e[:0], e[:0])
        uc, vc, ku, kv = np.empty((4, b - a), np.float32)  # loop 1 (vectorised) -> loop 2 (the gather)
        self._coordinates(points[0, a:b], points[1, a:b], points[2, a:b], R, t, self._K, self._D, self._r2max,
                          self._min_depth, self._u_max, self._v_max, uc, vc, ku, kv)
        _gather(self._maps, self._base[a:b], self._row, uc, vc, ku, kv, self._e_max, e[a:b], du, dv, derivatives)

    def gradient(self, points: np.ndarray, a: int, b: int, R: np.ndarray, t: np.ndarray, w: np.ndarray,
                 de_du: np.ndarray, de_dv: np.ndarray, out: np.ndarray) -> None:
        """``out`` (6,) float64 = the sum over points ``a:b`` of ``w[i] (de_du[i] du_i + de_dv[i]
        dv_i)``, ``(du_i, dv_i)`` the derivatives of point i's map coordinates with respect to
        ``(dt, dw)`` (the rotation's part still to be multiplied by the left Jacobian's transpose)."""
        self._gradient(points[0, a:b], points[1, a:b], points[2, a:b], R, t, self._K, self._D, self._r2max,
                       self._min_depth, w[a:b], de_du[a:b], de_dv[a:b], out)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _soft_histogram(offset, e, h):
    for i in range(e.size):
        b = np.int32(e[i])
        f = np.float64(e[i]) - b
        h[offset[i] + b] += 1.0 - f
        h[offset[i] + b + 1] += f


def soft_histogram(offset: np.ndarray, e: np.ndarray, size: int) -> np.ndarray:
    """(size,) float64 histogram: each point's weight split linearly between bins
    ``offset[i] + floor(e[i])`` and the next (``e >= 0``, float32; ``offset`` int32, its bin's
    row of the joint histogram), in one pass where ``bincount`` needed two and their temporaries.
    The last bin takes what a point at the top of the last row would put past it."""
    h = np.zeros(size + 1)
    _soft_histogram(offset, e, h)
    return h[:size]


@numba.njit(inline="always", **_JIT)
def _reflect(i, n):
    """Index i of a line of n mirrored about its ends (d c b a | a b c d | d c b a), once."""
    return -i - 1 if i < 0 else (2 * n - i - 1 if i >= n else i)


@numba.njit(**_JIT)
def _separable(x, taps_rows, taps_cols, out):
    n_r, n_c = x.shape
    rr, rc = taps_rows.size // 2, taps_cols.size // 2
    rows = np.zeros((n_r, n_c))
    for r in range(n_r):  # along the columns of x: whole rows at a time
        for k in range(taps_rows.size):
            w = taps_rows[k]
            src = _reflect(r + k - rr, n_r)
            for c in range(n_c):
                rows[r, c] += w * x[src, c]
    line = np.empty(n_c + 2 * rc)
    for r in range(n_r):  # along the rows: each padded once
        for c in range(n_c + 2 * rc):
            line[c] = rows[r, _reflect(c - rc, n_c)]
        for c in range(n_c):
            out[r, c] = 0.0
        for k in range(taps_cols.size):
            w = taps_cols[k]
            for c in range(n_c):
                out[r, c] += w * line[c + k]


def separable(x: np.ndarray, taps_rows: np.ndarray, taps_cols: np.ndarray) -> np.ndarray:
    """``x`` (float64, 2D) filtered by the symmetric ``taps_rows`` along its columns and
    ``taps_cols`` along its rows, the border reflected (``scipy.ndimage``'s "reflect", OpenCV's
    ``BORDER_REFLECT``) once: each filter's radius must be under the side it runs along."""
    if taps_rows.size // 2 >= x.shape[0] or taps_cols.size // 2 >= x.shape[1]:
        raise ValueError("a filter reaches past the far side of the array")
    out = np.empty(x.shape)
    _separable(np.ascontiguousarray(x, dtype=np.float64), np.asarray(taps_rows, np.float64),
               np.asarray(taps_cols, np.float64), out)
    return out


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _bin_slopes(table, offset, e, out):
    for i in range(e.size):
        j = offset[i] + np.int32(e[i])
        out[i] = table[j + 1] - table[j]


def bin_slopes(table: np.ndarray, offset: np.ndarray, e: np.ndarray, out: np.ndarray) -> None:
    """``out[i] = table[j + 1] - table[j]`` (float32), ``j = offset[i] + floor(e[i])``: what a
    score read through :func:`soft_histogram` gains per unit of each point's ``e``."""
    _bin_slopes(table, offset, e, out)


def e_bins(padded_map: np.ndarray, out: np.ndarray) -> None:
    """Fill ``out`` (H, W) uint8 with the E bin (nearest of 0..255) of each pixel of the
    (H+2, W+2) one-pixel-padded float32 map."""
    _e_bins_scene(padded_map, out)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _count_events(x, y, t, begin, end, grid):
    h, w = grid.shape
    inside = outside = 0
    for i in range(t.size):
        ti = t[i]
        if ti >= begin and ti < end:
            xi, yi = x[i], y[i]
            if 0 <= xi < w and 0 <= yi < h:
                grid[yi, xi] += 1
                inside += 1
            else:
                outside += 1
    return inside, outside


def count_events(x: np.ndarray, y: np.ndarray, t: np.ndarray, begin: int, end: int, grid: np.ndarray) -> tuple[int, int]:
    """Add one to ``grid[y, x]`` (H, W int64) for each event with ``begin <= t < end`` (integer
    x, y; int64 t); returns (events counted, events in the window but outside the grid). One pass, where numpy's
    select, bounds check and bincount made six (the accumulated map's cost after decoding)."""
    inside, outside = _count_events(x, y, t, np.int64(begin), np.int64(end), grid)
    return int(inside), int(outside)
