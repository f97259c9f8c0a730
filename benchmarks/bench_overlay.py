"""Slider-to-overlay latency at full size (1280x720 map, 75k lidar points), server side.

Part 1 times the renderer alone, as a slider move drives it: build the extrinsic from the six
slider values, project the points, draw them on the contrast-stretched map, JPEG-encode.
Part 2 times the running app (a real viser server, no browser needed): from the slider
callback's ``App.set_extrinsic`` to the new frame handed to viser (encoded, queued for every
tab), with the MI readout worker competing for the CPU as it does in use.
Part 1 also times the app's own drawing at the frame widths it sends (``render_view``: the map
scaled to the frame, outlined discs drawn into it) and the JPEG within the byte budget.
Part 2 reports previews and frames at rest at the 1366 and 1920 px windows' frame widths.
These are the server's legs only; the page's are in ``bench_browser_overlay.py``.
Target: <= 100 ms. Run: ``python benchmarks/bench_overlay.py [--repeats 20] [--no-app]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from l2e_studio.app.overlay import (
    OverlayStyle,
    compose_before_after,
    encode_jpeg,
    grey_rgb,
    intensity_colors,
    normalise_map,
    project_scene,
    render_overlay,
    render_view,
)
from l2e_studio.app.pose import extrinsic_from_sliders
from l2e_studio.camera import CameraModel
from l2e_studio.geometry import LIDAR_TO_CAMERA_AXES, Extrinsic
from l2e_studio.scenes import Scene, SceneSet



def full_size_scene(n_points: int, width: int, height: int, seed: int = 0):
    """A camera like the paper's (63x38 deg, radtan) and a 120x25 deg lidar scan in front of it."""
    rng = np.random.default_rng(seed)
    fx = (width / 2) / np.tan(np.radians(31.5))
    K = np.array([[fx, 0, width / 2 - 0.5], [0, fx, height / 2 - 0.5], [0, 0, 1]])
    camera = CameraModel(K, width, height, D=np.array([-0.08, 0.05, 0.001, -0.001, 0.0]))
    az = np.radians(rng.uniform(-60, 60, n_points))
    el = np.radians(rng.uniform(-12.5, 12.5, n_points))
    r = rng.uniform(3.0, 30.0, n_points)
    pts = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1)
    intensity = rng.uniform(0, 255, n_points).astype(np.float32)
    return camera, pts.astype(np.float32), intensity


def event_map_for(points, extrinsic, camera, seed: int = 1) -> np.ndarray:
    """A plausible accumulated map: counts where the laser hits at ``extrinsic``, plus noise."""
    rng = np.random.default_rng(seed)
    proj = project_scene(points, extrinsic, camera)
    m = rng.poisson(0.05, (camera.height, camera.width)).astype(np.float32)
    u = np.rint(proj.uv[:, 0]).astype(int)
    v = np.rint(proj.uv[:, 1]).astype(int)
    np.add.at(m, (v, u), rng.poisson(8.0, u.size).astype(np.float32))
    return m


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--points", type=int, default=75_000)
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    parser.add_argument("--repeats", type=int, default=60)
    parser.add_argument("--point-size", type=int, default=3)
    parser.add_argument("--scenes", type=int, default=40, help="scenes loaded in the app for part 2")
    parser.add_argument("--no-app", action="store_true", help="time the renderer only (part 1)")
    args = parser.parse_args()

    camera, pts, intensity = full_size_scene(args.points, args.width, args.height)
    T = np.eye(4)
    T[:3, :3] = LIDAR_TO_CAMERA_AXES  # lidar x forward, y left, z up -> optical camera frame
    T[:3, 3] = (0.05, -0.1, 0.02)
    seed = Extrinsic.from_matrix(T)
    event_map = event_map_for(pts, seed, camera)
    base = grey_rgb(normalise_map(event_map), 1.0)  # cached per scene + contrast in the app
    colors = intensity_colors(intensity)  # cached per scene in the app
    visible = project_scene(pts, seed, camera).index.size

    rows = []
    for color_by in ("intensity", "depth"):
        for opacity in (1.0, 0.8):
            style = OverlayStyle(color_by=color_by, point_size=args.point_size, opacity=opacity)
            times, sizes, encode = [], [], []
            for i in range(args.repeats):
                t0 = time.perf_counter()
                sliders = np.concatenate([seed.translation + 0.001 * i, (0.05 * i, -0.03 * i, 0.02 * i)])
                ext = extrinsic_from_sliders(sliders, seed)
                img = render_overlay(base, pts, ext, camera, style, colors)
                t1 = time.perf_counter()
                data = encode_jpeg(img, 80)
                t2 = time.perf_counter()
                times.append(t2 - t0)
                encode.append(t2 - t1)
                sizes.append(len(data))
            t = np.array(times[3:]) * 1e3
            rows.append((color_by, opacity, t.min(), np.median(t), np.percentile(t, 95),
                         np.median(encode[3:]) * 1e3, np.mean(sizes) / 1024))

    print(
        f"overlay latency, {args.width}x{args.height} map, {args.points} points "
        f"({visible} in the image), point size {args.point_size}px"
    )
    print(f"{'colour':>10} {'opacity':>8} {'min ms':>7} {'median ms':>10} {'p95 ms':>8} {'(jpeg ms)':>10} {'KiB':>7}")
    for color_by, opacity, lo, med, p95, enc, kib in rows:
        print(f"{color_by:>10} {opacity:>8.2f} {lo:>7.1f} {med:>10.1f} {p95:>8.1f} {enc:>10.1f} {kib:>7.0f}")

    frame_widths(args.width, args.height, args.repeats)

    ext_a = seed
    ext_b = seed.perturbed([0.02, 0, 0], [0, 0.01, 0])
    style = OverlayStyle(point_size=args.point_size)
    a = render_overlay(base, pts, ext_a, camera, style, colors)
    b = render_overlay(base, pts, ext_b, camera, style, colors)
    for mode in ("side by side", "swipe", "blend"):
        ts = []
        for _ in range(10):
            t0 = time.perf_counter()
            encode_jpeg(compose_before_after(a, b, mode, 0.5))
            ts.append(time.perf_counter() - t0)
        print(f"before/after compose+encode ({mode}): median {np.median(ts) * 1e3:.1f} ms")


    if not args.no_app:
        app_latency(camera, pts, intensity, event_map, seed, args.repeats, args.scenes)


def frame_widths(width: int, height: int, repeats: int) -> None:
    """The app's own drawing: ``render_view`` at the frame widths it sends (a preview 640 px; at
    rest 722 px in a 1366 px window, 1128 px in a 1920 px one), dense and sparse scans, then the
    JPEG within the 60 KB budget at the best quality (the frame at rest)."""
    from l2e_studio.app.panels.overlay_view import FRAME_BYTES, REST_QUALITIES, jpeg_within, panel_layout

    print("render_view at the frame's width (outlined discs, opacity 0.8), then JPEG within the budget "
          "(median / p95 ms):")
    for n_points, size, what in ((75_000, 2, "64-beam-like"), (20_000, 3, "16-beam-like")):
        camera, pts, intensity = full_size_scene(n_points, width, height)
        T = np.eye(4)
        T[:3, :3] = LIDAR_TO_CAMERA_AXES
        T[:3, 3] = (0.05, -0.1, 0.02)
        seed = Extrinsic.from_matrix(T)
        base = grey_rgb(normalise_map(event_map_for(pts, seed, camera)), 1.0)
        colors = intensity_colors(intensity)
        style = OverlayStyle(point_size=size, opacity=0.8, outline=1)
        for frame in (640, panel_layout(1366)[1], panel_layout(1920)[1]):
            draw, enc, quality = [], [], None
            for i in range(repeats):
                ext = seed.perturbed([0.001 * (i % 5), 0, 0], [0, 0.002 * (i % 3), 0])
                t0 = time.perf_counter()
                img = render_view(base, pts, ext, camera, style, colors, None, frame, frame)
                t1 = time.perf_counter()
                _, _, quality = jpeg_within(img, FRAME_BYTES, REST_QUALITIES, frame, quality)
                enc.append(time.perf_counter() - t1)
                draw.append(t1 - t0)
            d, e = np.array(draw[3:]) * 1e3, np.array(enc[3:]) * 1e3
            print(f"  {what} ({n_points} points), {frame} px: draw {np.median(d):.1f} / {np.percentile(d, 95):.1f}, "
                  f"JPEG {np.median(e):.1f} / {np.percentile(e, 95):.1f} (quality {quality})")


def app_latency(camera, pts, intensity, event_map, seed, repeats: int, n_scenes: int) -> None:
    """Slider callback -> frame handed to viser, and -> the score readout computed, through a
    running App, for the frame widths of a 1366 and a 1920 px wide window: a preview (what a
    change sends first) and a frame at rest (sent once the input rests)."""
    import socket
    from pathlib import Path
    from tempfile import mkdtemp

    from l2e_studio.app.panels.overlay_view import panel_layout
    from l2e_studio.app.server import build_app

    scenes = [Scene(f"scene_{i:03d}", pts, intensity, event_map, "events") for i in range(n_scenes)]
    tmp = Path(mkdtemp(prefix="l2e_bench_"))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    app = build_app(SceneSet(tmp, camera, seed, scenes), port=port, out_dir=tmp / "results")
    try:
        app.views.overlay_worker.wait_idle(30)
        app.views.mi_worker.wait_idle(60)
        print(f"through the app ({n_scenes} scenes loaded, MI readout live): slider -> frame handed to viser; "
              f"-> readout computed (median / p95 ms)")
        for window in (1366, 1920):
            app.overlay.display_width = panel_layout(window)[1]
            for rest in (False, True):
                frame, readout = [], []
                for i in range(repeats):
                    frames = app.overlay.frames
                    sliders = np.concatenate([seed.translation + 0.001 * (i % 7), (0.05 * i, -0.03 * i, 0.02 * i)])
                    app.views._want_rest = rest  # the next frame is the one at rest (as once the input rests)
                    t0 = time.perf_counter()
                    app.set_extrinsic(extrinsic_from_sliders(sliders, seed), source="sliders")
                    while app.overlay.frames == frames:
                        time.sleep(0.0005)
                    frame.append(time.perf_counter() - t0)
                    app.views.mi_worker.wait_idle(30)  # one slider step at a time, as a person moves it
                    readout.append(time.perf_counter() - t0)
                    time.sleep(0.3)  # the frame at rest and the table follow; then the next step
                    app.views.overlay_worker.wait_idle(10)
                f, r = np.array(frame[2:]) * 1e3, np.array(readout[2:]) * 1e3
                print(f"  {window} px window, frame {app.overlay.display_width if rest else min(app.overlay.display_width, 640)} px "
                      f"{'at rest' if rest else 'preview'}: frame {np.median(f):.0f} / {np.percentile(f, 95):.0f}; "
                      f"readout {np.median(r):.0f} / {np.percentile(r, 95):.0f}")
    finally:
        app.stop()


if __name__ == "__main__":
    main()
