"""The engine's per-point and per-pixel loops, compiled (numba): the nearest pixel of each
projected lidar point, the (L, E) pair counts the paper's MI is made of, the maps' E bins, the
smooth objectives' sample (projection, bilinear lookup and its derivatives by the pose, in one
pass), and the per-event count of a raw recording's window into its event map.

The reported MI reads every point of every scene at every evaluation (3M points for 40 scenes),
and the workbench's readout does it on each key press. As numpy expressions, projection with
lens distortion is some twenty passes over the points, each a temporary the size of the cloud;
one fused loop keeps each point in registers and lets the compiler vectorise it. Measured on 3M
points: numpy 60-80 ms, these kernels 8 ms on one core. The sample reads the float32 maps where
numpy needed a packed copy of 40 full-size maps (300 MB, 0.4-0.8 s per stage).

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
def _equidistant(x, y, D):
    r = np.sqrt(x * x + y * y)
    th = np.arctan(r)
    th2 = th * th
    thd = th * (1 + th2 * (D[0] + th2 * (D[1] + th2 * (D[2] + th2 * D[3]))))
    scale = thd / r if r >= 1e-8 else np.float32(1.0)
    return x * scale, y * scale


@numba.njit(inline="always", **_JIT)
def _pixel(xd, yd, z, K, W, H, min_depth):
    u = K[0] * xd + K[2] * yd + K[3]
    v = K[1] * yd + K[4]
    ok = (z > min_depth) & (u >= -0.5) & (u < W - 0.5) & (v >= -0.5) & (v < H - 0.5)
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
        out[i] = _pixel(xd, yd, zc, K, W, H, min_depth) if x * x + y * y <= r2max else np.int32(-1)


@numba.njit(**_JIT)
def _index_equidistant(px, py, pz, R, t, K, D, W, H, min_depth, r2max, out):
    for i in range(px.size):
        xc, yc, zc = _camera_xyz(px, py, pz, i, R, t)
        x, y = xc / zc, yc / zc
        xd, yd = _equidistant(x, y, D)
        out[i] = _pixel(xd, yd, zc, K, W, H, min_depth) if x * x + y * y <= r2max else np.int32(-1)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _count_pairs(pix, l_bins, e_bins, hist):
    for i in range(pix.size):
        p = pix[i]
        if p >= 0:
            hist[l_bins[i] * 256 + e_bins[p]] += 1


def pixel_index(
    points: np.ndarray, R: np.ndarray, t: np.ndarray, camera: CameraModel, min_depth: float,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """(N,) int32 flat index ``row * W + col`` of the pixel nearest each of the (3, N) float32
    lidar points at ``R p + t``, or -1 for a point behind ``min_depth``, beyond the lens's fold or off the image."""
    pts = np.asarray(points, dtype=np.float32)
    n = pts.shape[1]
    out = np.empty(n, np.int32) if out is None else out[:n]
    K = np.array([camera.K[0, 0], camera.K[1, 1], camera.K[0, 1], camera.K[0, 2], camera.K[1, 2]], np.float32)
    D = np.zeros(8, np.float32)
    D[: camera.D.size] = camera.D
    kernel = _index_equidistant if camera.model == "equidistant" else _index_radtan
    kernel(pts[0], pts[1], pts[2], np.asarray(R, np.float32), np.asarray(t, np.float32), K, D,
           camera.width, camera.height, np.float32(min_depth), np.float32(camera.max_r2), out)
    return out


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
def _radtan_jac(x, y, D):
    """The lens (float64) and its 2x2 Jacobian d(xd, yd)/d(x, y), as geometry.distort."""
    k1, k2, p1, p2, k3, k4, k5, k6 = D[0], D[1], D[2], D[3], D[4], D[5], D[6], D[7]
    r2 = x * x + y * y
    a = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    b = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    radial = a / b
    xy = x * y
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    da = k1 + r2 * (2.0 * k2 + r2 * 3.0 * k3)
    db = k4 + r2 * (2.0 * k5 + r2 * 3.0 * k6)
    drad = (da * b - a * db) / (b * b)
    cross = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y
    return (xd, yd, radial + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x, cross, cross,
            radial + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x)


@numba.njit(inline="always", **_JIT)
def _equidistant_jac(x, y, D):
    """The fisheye lens (float64) and its 2x2 Jacobian, as geometry.distort."""
    r = np.sqrt(x * x + y * y)
    if r < 1e-8:
        return x, y, 1.0, 0.0, 0.0, 1.0
    th = np.arctan(r)
    th2 = th * th
    thd = th * (1.0 + th2 * (D[0] + th2 * (D[1] + th2 * (D[2] + th2 * D[3]))))
    scale = thd / r
    dthd = 1.0 + th2 * (3.0 * D[0] + th2 * (5.0 * D[1] + th2 * (7.0 * D[2] + th2 * 9.0 * D[3])))
    ds_r = (dthd / (1.0 + r * r) * r - thd) / (r * r * r)  # d(scale)/dr / r
    return x * scale, y * scale, scale + x * x * ds_r, x * y * ds_r, x * y * ds_r, scale + y * y * ds_r


_BLOCK = 256  # points per block: their temporaries (35 KB) stay in the nearest caches


@numba.njit(**_JIT)
def _sample_pose(px, py, pz, base, R, t, K, D, model, min_depth, r2max, maps, row, u_max, v_max, e_max,
                 e, d, gradient):
    # Three passes per block: the projection, then the map reads alone (a tight loop keeps many
    # cache misses in flight: the maps of 40 full-size scenes are 150 MB), then the chain rule.
    B = _BLOCK
    k_ = np.empty(B, np.int64)
    f_ = np.empty((2, B))  # the bilinear fractions
    m_ = np.empty((4, B), np.float32)  # the four neighbours
    c_ = np.empty((12, B))  # what the chain rule needs: du, dv gates and factors, 1/z, x, y, q
    for s in range(0, px.size, B):
        nb = min(B, px.size - s)
        for j in range(nb):
            i = s + j
            X, Y, Z = np.float64(px[i]), np.float64(py[i]), np.float64(pz[i])
            qx = R[0, 0] * X + R[0, 1] * Y + R[0, 2] * Z
            qy = R[1, 0] * X + R[1, 1] * Y + R[1, 2] * Z
            qz = R[2, 0] * X + R[2, 1] * Y + R[2, 2] * Z
            zc = qz + t[2]
            inv_z = 1.0 / max(zc, min_depth)
            x = (qx + t[0]) * inv_z
            y = (qy + t[1]) * inv_z
            front = zc > min_depth and x * x + y * y <= r2max
            if model == 1:
                xd, yd, jxx, jxy, jyx, jyy = _radtan_jac(x, y, D)
            elif model == 2:
                xd, yd, jxx, jxy, jyx, jyy = _equidistant_jac(x, y, D)
            else:
                xd, yd, jxx, jxy, jyx, jyy = x, y, 1.0, 0.0, 0.0, 1.0
            # packed-map coordinates: map pixel (0, 0) sits at (1, 1) of the zero-padded map
            u = K[0] * xd + K[2] * yd + K[3] + 1.0
            v = K[1] * yd + K[4] + 1.0
            uc = min(u, u_max) if u >= 0.0 else 0.0  # NaN (an overflowed lens) reads pixel 0
            vc = min(v, v_max) if v >= 0.0 else 0.0
            if not front:
                uc = 0.0
            uf, vf = np.floor(uc), np.floor(vc)
            f_[0, j], f_[1, j] = uc - uf, vc - vf
            k_[j] = base[i] + np.int64(vf) * row + np.int64(uf)
            if gradient:
                # the lookup's derivatives are zero where the point was clamped to the border or is unseen
                c_[0, j] = 0.0 if (u <= 0.0 or u >= u_max or not front) else 1.0
                c_[1, j] = 0.0 if (v <= 0.0 or v >= v_max or not front) else 1.0
                # d(u, v)/d(x, y): du/dx, du/dy, dv/dx, dv/dy
                c_[2, j], c_[3, j] = K[0] * jxx + K[2] * jyx, K[0] * jxy + K[2] * jyy
                c_[4, j], c_[5, j] = K[1] * jyx, K[1] * jyy
                c_[6, j], c_[7, j], c_[8, j] = inv_z, x, y
                c_[9, j], c_[10, j], c_[11, j] = qx, qy, qz
        for j in range(nb):
            k = k_[j]
            m_[0, j], m_[1, j], m_[2, j], m_[3, j] = maps[k], maps[k + 1], maps[k + row], maps[k + row + 1]
        for j in range(nb):
            i = s + j
            m00, m01, m10, m11 = np.float64(m_[0, j]), np.float64(m_[1, j]), np.float64(m_[2, j]), np.float64(m_[3, j])
            fu, fv = f_[0, j], f_[1, j]
            top = m00 + fu * (m01 - m00)
            bot = m10 + fu * (m11 - m10)
            e[i] = min(top + fv * (bot - top), e_max)
            if not gradient:
                continue
            de_du = c_[0, j] * ((m01 - m00) + fv * ((m11 - m10) - (m01 - m00)))
            de_dv = c_[1, j] * (bot - top)
            # chain through d(u, v)/d(x, y) and d(x, y)/d(X, Y, Z) of the camera-frame point
            gx = de_du * c_[2, j] + de_dv * c_[4, j]
            gy = de_du * c_[3, j] + de_dv * c_[5, j]
            inv_z, x, y = c_[6, j], c_[7, j], c_[8, j]
            gX, gY = gx * inv_z, gy * inv_z
            gZ = -(gx * x + gy * y) * inv_z
            qx, qy, qz = c_[9, j], c_[10, j], c_[11, j]
            d[0, i], d[1, i], d[2, i] = gX, gY, gZ
            # rotation: d X_cam / d dw = -[Q]x J_l(dw), so de/d(dw) = J_l^T (Q x g)
            d[3, i] = qy * gZ - qz * gY
            d[4, i] = qz * gX - qx * gZ
            d[5, i] = qx * gY - qy * gX


def sample_pose(
    points: np.ndarray, base: np.ndarray, R: np.ndarray, t: np.ndarray, camera: CameraModel, min_depth: float,
    maps: np.ndarray, row: int, rows: int, e_max: float, e: np.ndarray, d: np.ndarray | None = None,
) -> None:
    """The smooth objectives' per-point work at pose ``R p + t``, in float64: each (3, N)
    float32 lidar point projected through ``camera``, its scene's map read bilinearly there
    (clamped to the map's one-pixel zero padding, at most ``e_max``) into ``e``, and, with ``d``
    (6, N), the reading's derivative by ``(dt, dw)`` of a left correction ``R = exp(dw) R0``,
    ``t = t0 + dt`` (rotation rows before the left Jacobian). The maps are flat: pixel (x, y) of
    a point's map is ``maps[base + (y + 1) * row + x + 1]``, each padded map ``row`` wide and
    ``rows`` high. Points behind ``min_depth`` or past the lens's fold read the padding and have
    zero derivative, as do those clamped to the border."""
    K = np.array([camera.K[0, 0], camera.K[1, 1], camera.K[0, 1], camera.K[0, 2], camera.K[1, 2]], np.float64)
    D = np.zeros(8, np.float64)
    D[: camera.D.size] = camera.D
    model = 0 if not camera.is_distorted else 2 if camera.model == "equidistant" else 1
    gradient = d is not None
    _sample_pose(points[0], points[1], points[2], base, np.asarray(R, np.float64), np.asarray(t, np.float64),
                 K, D, model, float(min_depth), float(camera.max_r2), maps, np.int64(row),
                 float(row - 1) - 1e-3, float(rows - 1) - 1e-3, float(e_max), e, d if gradient else np.empty((6, 0), np.float32),
                 gradient)


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
