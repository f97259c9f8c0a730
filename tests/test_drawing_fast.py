"""The overlay's faster drawing (a cached scaled map, OpenCV's RGBA -> RGB) draws exactly what the
drawing it replaced drew: the same bytes for dense and sparse scans, shrunk, zoomed, blended,
outlined and depth-ordered; the JPEG search that starts from the last quality finds what
the full search finds."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from l2e_studio.app.overlay import OverlayStyle, grey_rgb, intensity_colors, project_scene, render_view, scaled_window
from l2e_studio.camera import CameraModel
from l2e_studio.drawing import _disc_kernel, disc_size
from l2e_studio.geometry import LIDAR_TO_CAMERA_AXES, Extrinsic


def old_draw_points(base, uv, colors, point_size=2, opacity=1.0, depth=None, outline=0):
    """drawing.draw_points as it was before the change (the reference for the look)."""
    h, w = base.shape[:2]
    out = base.copy()
    u = np.rint(uv[:, 0]).astype(np.int32)
    v = np.rint(uv[:, 1]).astype(np.int32)
    ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    u, v, colors = u[ok], v[ok], colors[ok]
    if u.size == 0:
        return out
    if depth is not None and u.size > 1:
        order = np.argsort(-np.asarray(depth)[ok])
        u, v, colors = u[order], v[order], colors[order]
    rank = np.zeros((h, w), np.float32)
    rank[v, u] = np.arange(1, u.size + 1, dtype=np.float32)
    if point_size > 1:
        kernel, anchor = _disc_kernel(int(point_size))
        rank = cv2.dilate(rank, kernel, anchor=anchor)
    palette = np.zeros((u.size + 1, 4), np.uint8)
    palette[1:, :3] = colors
    layer = palette.view(np.uint32).ravel()[rank.astype(np.int32)]
    layer = np.ascontiguousarray(layer.view(np.uint8).reshape(h, w, 4)[:, :, :3])
    if opacity < 1.0:
        layer = cv2.addWeighted(base, 1.0 - float(opacity), layer, float(opacity), 0.0)
    mask = (rank > 0).view(np.uint8)
    if outline > 0:
        ring = cv2.dilate(mask, np.ones((2 * int(outline) + 1,) * 2, np.uint8))
        cv2.copyTo(np.right_shift(out, 2), ring, out)
    cv2.copyTo(layer, mask, out)
    return out


def old_render_view(base_rgb, points, extrinsic, camera, style, intensity_rgb, window, width, screen_width, pixelated):
    """overlay.render_view as it was: the map window resized on every call, then the old drawing."""
    h, w = base_rgb.shape[:2]
    x0, y0, ww, wh = window if window is not None else (0, 0, w, h)
    out_w = int(width) if width else ww
    out_h = max(1, int(round(wh * out_w / ww)))
    crop = base_rgb[y0 : y0 + wh, x0 : x0 + ww]
    if (out_w, out_h) != (ww, wh):
        interp = cv2.INTER_NEAREST if pixelated else cv2.INTER_AREA if out_w < ww else cv2.INTER_LINEAR
        crop = cv2.resize(crop, (out_w, out_h), interpolation=interp)
    else:
        crop = np.ascontiguousarray(crop)
    proj = project_scene(points, extrinsic, camera)
    colors = intensity_rgb[proj.index] if style.color_by == "intensity" else None
    if colors is None:
        from l2e_studio.drawing import depth_colors
        colors = depth_colors(proj.depth)
    sx, sy = out_w / ww, out_h / wh
    uv = np.column_stack(((proj.uv[:, 0] + 0.5 - x0) * sx - 0.5, (proj.uv[:, 1] + 0.5 - y0) * sy - 0.5))
    per_screen = out_w / float(screen_width) if screen_width else 1.0
    size = disc_size(style.point_size, per_screen)
    outline = disc_size(style.outline, per_screen) if style.outline else 0
    return old_draw_points(crop, uv, colors, size, style.opacity, proj.depth, outline)


def scan(n_points: int, width: int = 640, height: int = 360, seed: int = 0):
    """A wide lidar scan in front of a 63-deg camera and a noisy grey map (as benchmarks/bench_overlay.py)."""
    rng = np.random.default_rng(seed)
    fx = (width / 2) / np.tan(np.radians(31.5))
    cam = CameraModel(np.array([[fx, 0, width / 2 - 0.5], [0, fx, height / 2 - 0.5], [0, 0, 1]]), width, height,
                      D=np.array([-0.08, 0.05, 0.001, -0.001, 0.0]))
    az, el = np.radians(rng.uniform(-60, 60, n_points)), np.radians(rng.uniform(-12.5, 12.5, n_points))
    r = rng.uniform(3.0, 30.0, n_points)
    pts = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1).astype(np.float32)
    T = np.eye(4)
    T[:3, :3] = LIDAR_TO_CAMERA_AXES
    T[:3, 3] = (0.05, -0.1, 0.02)
    base = grey_rgb(rng.uniform(0, 1, (height, width)).astype(np.float32))
    return cam, pts, intensity_colors(rng.uniform(0, 255, n_points)), Extrinsic.from_matrix(T), base


@pytest.mark.parametrize("n_points, point_size", [(20_000, 2), (5_000, 3)])  # dense (64-beam-like), sparse
@pytest.mark.parametrize("width, window", [(564, None), (361, None), (320, None), (640, None),
                                           (640, (100, 50, 160, 90)), (160, (100, 50, 160, 90))])
# shrunk by odd and even factors; a 4x zoom; a window at 1:1 (a view of the map, not a copy)
@pytest.mark.parametrize("opacity, outline, color_by", [(1.0, 0, "intensity"), (0.8, 1, "depth")])
def test_render_view_draws_the_same_bytes_as_before(n_points, point_size, width, window, opacity, outline, color_by):
    cam, pts, colors, ext, base = scan(n_points)
    style = OverlayStyle(color_by=color_by, point_size=point_size, opacity=opacity, outline=outline)
    pixelated = window is not None
    want = old_render_view(base, pts, ext, cam, style, colors, window, width, width, pixelated)
    for _ in range(2):  # drawn afresh, then on the cached map
        got = render_view(base, pts, ext, cam, style, colors, window, width, width, pixelated)
        assert got.shape == want.shape and np.array_equal(got, want)
    assert np.count_nonzero(np.any(got != scaled_window(base, window or (0, 0, 640, 360), got.shape[1::-1],
                                                         pixelated), axis=2)) > 1000  # the points are there


def test_scaled_map_is_kept_per_base_array_and_not_writable():
    cam, pts, colors, ext, base = scan(2_000)
    other = 255 - base  # same shape, other picture
    a = scaled_window(base, (0, 0, 640, 360), (451, 254))
    assert scaled_window(base, (0, 0, 640, 360), (451, 254)) is a  # kept
    b = scaled_window(other, (0, 0, 640, 360), (451, 254))
    assert np.array_equal(b, cv2.resize(other, (451, 254), interpolation=cv2.INTER_AREA))
    assert not np.array_equal(a, b) and not a.flags.writeable
    style = OverlayStyle(point_size=2, outline=1)
    drawn = render_view(other, pts, ext, cam, style, colors, None, 451, 451)
    assert np.array_equal(drawn, old_render_view(other, pts, ext, cam, style, colors, None, 451, 451, False))


def test_jpeg_search_from_the_last_quality_finds_the_same_answer_in_two_encodes(monkeypatch):
    from l2e_studio.app.panels import overlay_view
    from l2e_studio.app.panels.overlay_view import REST_QUALITIES, jpeg_within

    cam, pts, colors, ext, base = scan(20_000)
    frame = render_view(base, pts, ext, cam, OverlayStyle(point_size=2, outline=1), colors, None, 564, 564)
    encodes = []
    real = overlay_view.encode_jpeg
    monkeypatch.setattr(overlay_view, "encode_jpeg", lambda img, q: encodes.append(q) or real(img, q))
    for budget in (10**7, 150_000, 110_000, 90_000, 80_000, 20_000, 2_000):  # top, middle, bottom; shrunk
        want = jpeg_within(frame, budget, REST_QUALITIES)
        for start in (None, *REST_QUALITIES):
            encodes.clear()
            got = jpeg_within(frame, budget, REST_QUALITIES, start=start)
            assert got[1] == want[1] and got[2] == want[2] and got[0].shape == want[0].shape
            assert len(got[1]) <= budget or got[0].shape[1] <= 320
            if start == want[2] and got[0].shape == frame.shape:
                assert len(encodes) <= 2  # the answer and its better neighbour


def test_the_extrinsics_transform_keeps_dtype_and_shape_and_matches_the_matrix_product():
    cam, pts, colors, ext, base = scan(5_000)
    ext = ext.perturbed([0.3, -0.2, 0.1], [0.05, -0.02, 0.03])
    for points in (pts, pts.astype(np.float64), pts[:1], pts[:0], pts[0]):
        got = ext.transform(points)
        want = (np.asarray(points, np.float64) @ ext.R.T + ext.translation)
        assert got.dtype == points.dtype and got.shape == points.shape
        tol = 1e-5 if points.dtype == np.float32 else 1e-12
        assert np.allclose(got, want, rtol=tol, atol=tol)
    assert np.abs(ext.transform(pts) - pts).max() > 0.1  # it did move them
