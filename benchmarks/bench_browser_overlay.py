"""Slider change -> overlay changed *in the browser*, at N full-size scenes (default 40).

A real app (viser server in this process) and headless Debian Chromium (Playwright). In the
page, a ``keydown`` listener stamps each input, a ``MutationObserver`` stamps each new overlay
image (``src`` swapped to a new blob) once the browser has decoded it, and the blob's size is
what was shipped for that update. A second observer stamps the MI readout's text changes.

Two patterns of input on the focused yaw slider (one 0.1 deg step per key press):
- ``steps``: one press, then wait until the page settles (a person nudging);
- ``drag``: a press every ``--drag-ms`` (a drag: inputs arrive faster than frames).
Latency of an input = first overlay frame decoded after it - the input. Bytes per update =
mean size of the images that arrived while inputs were coming (the per-tab cost).

Run: ``python benchmarks/bench_browser_overlay.py [--scenes 40] [--presses 30]``.
Targets (issue 10): median <= 100 ms, p95 <= 200 ms, <= 60 KB per update per tab.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from tempfile import mkdtemp

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_overlay import event_map_for, full_size_scene  # noqa: E402

from l2e_studio.app.screenshot import CHROMIUM_ARGS, free_port  # noqa: E402
from l2e_studio.geometry import LIDAR_TO_CAMERA_AXES, Extrinsic  # noqa: E402
from l2e_studio.scenes import Scene, SceneSet  # noqa: E402

CHROMIUM = "/usr/bin/chromium"

OBSERVE = """
() => {
  window.__inputs = []; window.__frames = []; window.__readouts = [];
  document.addEventListener('keydown', () => window.__inputs.push(performance.now()), true);
  const overlay = () => document.querySelector("img[src^='blob:']");
  new MutationObserver((muts) => {
    for (const m of muts) {
      const img = m.target;
      if (!(img instanceof HTMLImageElement) || img !== overlay() || !img.src.startsWith('blob:')) continue;
      const src = img.src;
      img.decode().then(() => {
        const t = performance.now();
        fetch(src).then(r => r.blob()).then(b => window.__frames.push([t, b.size]))
                  .catch(() => window.__frames.push([t, -1]));
      }).catch(() => {});
    }
  }).observe(document.body, {subtree: true, attributes: true, attributeFilter: ['src']});
  const readout = Array.from(document.querySelectorAll('p, div'))
      .filter(e => e.textContent.includes('included scenes:'))
      .sort((a, b) => a.textContent.length - b.textContent.length)[0];
  if (readout) new MutationObserver(() => window.__readouts.push(performance.now()))
      .observe(readout, {subtree: true, childList: true, characterData: true});
  return !!readout;
}
"""


def build_scene_set(n: int, points: int, width: int, height: int) -> SceneSet:
    camera, pts, intensity = full_size_scene(points, width, height)
    T = np.eye(4)
    T[:3, :3] = LIDAR_TO_CAMERA_AXES
    T[:3, 3] = (0.05, -0.1, 0.02)
    seed = Extrinsic.from_matrix(T)
    event_map = event_map_for(pts, seed, camera)
    # the same picture, in arrays of their own (memory as with n real scenes)
    scenes = [Scene(f"scene_{i:03d}", pts.copy(), intensity.copy(), event_map.copy(), "events") for i in range(n)]
    return SceneSet(Path(mkdtemp(prefix="l2e_bench_")), camera, seed, scenes)


RECEIVED: list[float] = []  # epoch ms at which the server received each extrinsic change
QUEUED: list[float] = []  # epoch ms at which each frame was encoded and queued


def instrument(app) -> list[float]:
    """Time, in the server, from each extrinsic change to the end of the first frame after it."""
    pending: list[float] = []
    out: list[float] = []
    set_ext, render = app.set_extrinsic, app.overlay.render

    def timed_set(*a, **k):
        pending.append(time.perf_counter())
        RECEIVED.append(time.time() * 1e3)
        return set_ext(*a, **k)

    def timed_render(*a, **k):
        started = time.perf_counter()
        done = [t for t in pending if t <= started]
        render(*a, **k)
        end = time.perf_counter()
        QUEUED.append(time.time() * 1e3)
        out.extend(end - t for t in done)
        del pending[:len(done)]

    app.set_extrinsic, app.overlay.render = timed_set, timed_render
    return out


def first_after(times: np.ndarray, t: float) -> float | None:
    later = times[times > t]
    return float(later.min()) if later.size else None


def latencies(inputs: list[float], frames: list[list[float]]) -> np.ndarray:
    ft = np.array([f[0] for f in frames]) if frames else np.zeros(0)
    out = [first_after(ft, t) - t for t in inputs if first_after(ft, t) is not None]
    return np.array(out)


def legs(inputs: np.ndarray, received: np.ndarray, queued: np.ndarray, shown: np.ndarray) -> None:
    """Where a step's latency goes (epoch ms; the page and the server share the machine's clock)."""
    a, b, c = [], [], []
    for t in inputs:
        r = first_after(received, t)
        q = first_after(queued, r) if r is not None else None
        f = first_after(shown, q) if q is not None else None
        if f is not None:
            a.append(r - t), b.append(q - r), c.append(f - q)
    if a:
        print(f"  legs (median): key press -> server receives {np.median(a):.0f} ms; -> frame queued "
              f"{np.median(b):.0f} ms; -> frame shown {np.median(c):.0f} ms")


def summary(name: str, lat: np.ndarray, sizes: list[float]) -> str:
    if lat.size == 0:
        return f"{name}: no frames"
    kb = np.array([s for s in sizes if s > 0]) / 1000.0
    return (f"{name}: {lat.size} inputs, latency median {np.median(lat):.0f} ms, p95 {np.percentile(lat, 95):.0f} ms, "
            f"max {lat.max():.0f} ms; {len(sizes)} frames, {kb.mean() if kb.size else float('nan'):.1f} KB per update "
            f"(max {kb.max() if kb.size else float('nan'):.1f} KB)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=40)
    parser.add_argument("--points", type=int, default=75_000)
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    parser.add_argument("--presses", type=int, default=30)
    parser.add_argument("--drag-ms", type=float, default=40.0)
    parser.add_argument("--viewport", default="1366x768")
    parser.add_argument("--no-3d", action="store_true", help="diagnosis: leave the 3D gizmo still")
    parser.add_argument("--no-mi", action="store_true", help="diagnosis: no MI readout updates")
    parser.add_argument("--cloud-step", type=int, default=1, help="diagnosis: show every k-th point in the 3D view")
    args = parser.parse_args()

    from playwright.sync_api import sync_playwright

    from l2e_studio.app.server import build_app

    t0 = time.perf_counter()
    scene_set = build_scene_set(args.scenes, args.points, args.width, args.height)
    app = build_app(scene_set, port=free_port(), out_dir=scene_set.root / "results")
    print(f"{args.scenes} scenes of {args.width}x{args.height}, {args.points} points; app up in "
          f"{time.perf_counter() - t0:.1f} s", flush=True)
    vw, vh = (int(v) for v in args.viewport.split("x"))
    server_lat = instrument(app)
    if args.no_3d:
        app.view3d.show_pose = lambda extrinsic: None
    if args.cloud_step > 1:
        app.view3d.cloud.points = app.view3d.cloud.points[:: args.cloud_step]
        app.view3d.cloud.colors = app.view3d.cloud.colors[:: args.cloud_step]
    if args.no_mi:
        app.mi_worker.poke = lambda: None
    try:
        app.overlay.point_size.value = 3
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": vw, "height": vh})
            page.goto(app.url)
            page.get_by_text("Use in optimisation").wait_for(timeout=60_000)
            page.get_by_role("tab", name="Seed").click()
            page.get_by_text("included scenes:").wait_for(timeout=60_000)
            app.overlay_worker.wait_idle(30)
            app.mi_worker.wait_idle(60)
            time.sleep(1.0)
            assert page.evaluate(OBSERVE), "MI readout element not found"
            label = page.locator("label", has_text="yaw (°)").first.get_attribute("for")
            thumb = page.locator(f"[id='{label}']").get_by_role("slider")
            thumb.focus()

            # steps: one press, then let everything settle
            for i in range(args.presses):
                page.keyboard.press("ArrowRight" if i % 2 == 0 else "ArrowLeft")
                app.overlay_worker.wait_idle(10)
                app.mi_worker.wait_idle(30)
                time.sleep(0.4)
            data = page.evaluate("() => [window.__inputs, window.__frames, window.__readouts]")
            inputs, frames, readouts = data
            print(summary("steps (one key press, then rest)", latencies(inputs, frames), [f[1] for f in frames]))
            origin = page.evaluate("() => performance.timeOrigin")
            legs(np.array(inputs) + origin, np.array(RECEIVED), np.array(QUEUED), np.array([f[0] for f in frames]) + origin)
            rt = np.array(readouts)
            rl = np.array([first_after(rt, t) - t for t in inputs if first_after(rt, t) is not None])
            if rl.size:
                print(f"  MI readout shown after a step: median {np.median(rl):.0f} ms, p95 {np.percentile(rl, 95):.0f} ms")

            # drag: presses faster than frames
            page.evaluate("() => { window.__inputs = []; window.__frames = []; window.__readouts = []; }")
            for i in range(args.presses * 2):
                page.keyboard.press("ArrowRight" if (i // 10) % 2 == 0 else "ArrowLeft")
                time.sleep(args.drag_ms / 1000.0)
            t_end = page.evaluate("() => performance.now()")
            time.sleep(1.5)
            inputs, frames, _ = page.evaluate("() => [window.__inputs, window.__frames, window.__readouts]")
            during = [f for f in frames if f[0] <= t_end + 100]
            print(summary(f"drag (a key press every {args.drag_ms:.0f} ms)", latencies(inputs, frames),
                          [f[1] for f in during]))
            rest = [f for f in frames if f[0] > t_end + 100]
            if rest:
                print(f"  at rest after the drag: {len(rest)} frame(s), last {rest[-1][1] / 1000:.1f} KB")
            # the scene table: a click on a row selects its scene (overlay of that scene shown)
            # viser's "WebGL in software mode" notice may lie over the tabs: close notices first
            for close in page.locator(".mantine-Notification-root button").all():
                close.click()
            page.get_by_role("tab", name="Scenes").click()
            page.get_by_role("cell", name="scene_000").first.wait_for(timeout=30_000)
            rng = np.random.default_rng(0)
            click_lat, selected_at = [], []
            real_select = app.select_scene
            app.select_scene = lambda i: (selected_at.append(time.time() * 1e3), real_select(i))[1]
            origin = page.evaluate("() => performance.timeOrigin")
            reached, queued = [], []
            for k in rng.choice(args.scenes, size=min(10, args.scenes), replace=False):
                name = f"scene_{int(k):03d}"
                cell = page.locator("td", has_text=name).first
                cell.scroll_into_view_if_needed()
                app.overlay_worker.wait_idle(10)
                page.evaluate("() => { window.__frames = []; }")
                t_click = page.evaluate("() => performance.now()")
                cell.dispatch_event("click")
                deadline = time.monotonic() + 10
                while time.monotonic() < deadline:
                    frames = page.evaluate("() => window.__frames")
                    if frames and app.state.snapshot().selected == int(k):
                        click_lat.append(frames[0][0] - t_click)
                        if selected_at:
                            reached.append(selected_at[-1] - (origin + t_click))
                            q = first_after(np.array(QUEUED), selected_at[-1])
                            queued.append(np.nan if q is None else q - selected_at[-1])
                        break
                    time.sleep(0.01)
            if click_lat:
                cl = np.array(click_lat)
                print(f"table row click -> that scene's overlay shown: median {np.median(cl):.0f} ms, max {cl.max():.0f} ms "
                      f"({cl.size} clicks, {args.scenes} rows); the click reached the server after "
                      f"{np.median(reached) if reached else float('nan'):.0f} ms, its frame was queued "
                      f"{np.nanmedian(queued) if queued else float('nan'):.0f} ms after that (medians)")
            srv = np.array(app.overlay_seconds[-50:]) * 1e3
            print(f"  server render+encode per frame: median {np.median(srv):.0f} ms")
            sl = np.array(server_lat) * 1e3
            if sl.size:
                print(f"  server side, change received -> its frame encoded and queued: median {np.median(sl):.0f} ms, "
                      f"p95 {np.percentile(sl, 95):.0f} ms")
            browser.close()
    finally:
        app.stop()
    import resource
    print(f"peak memory of the app's process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
