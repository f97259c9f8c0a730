"""What a person sees: key press on the seed slider -> the new overlay *painted*, in a real browser.

A real app (viser server in this process, 40 full-size scenes by default) and headless Debian
Chromium (Playwright), at each ``--viewport`` and each ``--delay-ms`` (0: direct; 40: through
``delay_proxy.py``, 40 ms each way, the bytes of the page and its websocket alike).

In the page, every time is ``performance.now()``:
- an input is the focused yaw slider's ``keydown``, stamped at ``event.timeStamp`` (when the
  browser made the event: a busy page that handles it late is counted, not hidden);
- a frame is painted when its ``<img>`` got the new ``src``, ``img.decode()`` resolved, the next
  animation frame ran and a task after it (the paint of that animation frame) began;
- the readout is painted likewise after its text changed.
Each frame the page paints is matched to the frame the server sent (SHA-1 of the JPEG), so it is
known which input (state version), scene and kind (preview / at rest) it shows.

Measured, median / p95 over inputs:
- ``first change``: one press, then rest: the key press -> the first new overlay painted;
- ``at rest``: the same press -> the frame at rest painted (quiet time + render + transport);
- ``readout``: the same press -> the score readout painted;
- ``held key``: a key held down (auto-repeat every ``--repeat-ms``): each input -> the first
  painted frame that shows it (or a later input); bytes per update;
- ``scene switch``: a click on a scene table row -> that scene's overlay painted.
``legs`` splits the first change: key -> server got the change -> frame handed to viser ->
``src`` set in the page -> decoded -> painted.

Run: ``python benchmarks/bench_browser_overlay.py [--viewports 1366x768,1920x1080] [--delays 0,40]``.
Targets (issue 17): first change <= 100 ms median / <= 200 ms p95 direct, <= RTT + 100 ms
through the proxy; frame at rest <= 400 ms; scene switch <= 300 ms.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import threading
import time
from pathlib import Path
from tempfile import mkdtemp

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_overlay import event_map_for, full_size_scene  # noqa: E402
from delay_proxy import DelayProxy  # noqa: E402

from l2e_studio.app.panels import overlay_view  # noqa: E402
from l2e_studio.app.screenshot import CHROMIUM_ARGS, free_port  # noqa: E402
from l2e_studio.geometry import LIDAR_TO_CAMERA_AXES, Extrinsic  # noqa: E402
from l2e_studio.scenes import Scene, SceneSet  # noqa: E402

CHROMIUM = "/usr/bin/chromium"

OBSERVE = """
() => {
  const W = window.__b = {inputs: [], frames: [], readouts: [], long: []};
  document.addEventListener('keydown', (e) => W.inputs.push(e.timeStamp), true);
  const painted = (cb) => requestAnimationFrame(() => {
    const ch = new MessageChannel(); ch.port1.onmessage = () => cb(performance.now()); ch.port2.postMessage(0);
  });
  const overlay = () => document.querySelector("img[src^='blob:']");
  const onImage = (img) => {
    const tSrc = performance.now(), src = img.src;
    const bytes = fetch(src).then(r => r.arrayBuffer()).catch(() => null);  // before the URL is revoked
    img.decode().then(() => {
      const tDec = performance.now();
      painted((tPaint) => bytes.then(async (buf) => {
        let sha = '';
        if (buf) sha = Array.from(new Uint8Array(await crypto.subtle.digest('SHA-1', buf)))
                           .map(b => b.toString(16).padStart(2, '0')).join('').slice(0, 16);
        W.frames.push([tSrc, tDec, tPaint, sha]);
      }));
    }).catch(() => {});  // replaced before it was decoded: never painted
  };
  new MutationObserver((muts) => {
    for (const m of muts) {
      const img = m.target;
      if (img instanceof HTMLImageElement && img === overlay() && img.src.startsWith('blob:')) onImage(img);
    }
  }).observe(document.body, {subtree: true, attributes: true, attributeFilter: ['src']});
  const readout = Array.from(document.querySelectorAll('p, div'))
      .filter(e => e.textContent.includes('included scenes:'))
      .sort((a, b) => a.textContent.length - b.textContent.length)[0];
  if (readout) new MutationObserver(() => painted((t) => W.readouts.push(t)))
      .observe(readout, {subtree: true, childList: true, characterData: true});
  try {
    new PerformanceObserver((l) => { for (const e of l.getEntries()) W.long.push([e.startTime, e.duration]); })
      .observe({type: 'longtask', buffered: false});
  } catch (e) {}
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
    # the same picture, in arrays of their own (memory and caches as with n real scenes)
    scenes = [Scene(f"scene_{i:03d}", pts.copy(), intensity.copy(), event_map.copy(), "events") for i in range(n)]
    return SceneSet(Path(mkdtemp(prefix="l2e_bench_")), camera, seed, scenes)


class ServerLog:
    """Server-side stamps (epoch ms): each slider change received, each frame handed to viser."""

    def __init__(self, app) -> None:
        self.changes: list[tuple[float, int]] = []  # (t, state version after it)
        # sha -> every sending of those bytes: (t, version, scene, rest, bytes); nudging back and
        # forth sends the same picture again for a newer state
        self.frames: dict[str, list[tuple[float, int, int, bool, int]]] = {}
        state, set_ext = app.state, app.set_extrinsic
        send = overlay_view.send_jpeg

        def timed_set(extrinsic, source: str = "", values=None):
            t = time.time() * 1e3
            set_ext(extrinsic, source, values)
            if source == "sliders":
                self.changes.append((t, state.snapshot().version))

        def logged_send(handle, image, data):
            sha = hashlib.sha1(data).hexdigest()[:16]
            meta = getattr(app.overlay, "sending", None)
            version, scene, is_rest = meta if meta is not None else (-1, -1, False)
            self.frames.setdefault(sha, []).append((time.time() * 1e3, version, scene, is_rest, len(data)))
            return send(handle, image, data)

        app.set_extrinsic = timed_set
        overlay_view.send_jpeg = logged_send
        render = app.overlay.render

        def tagged_render(snap, rest: bool = True):
            app.overlay.sending = (snap.version, snap.selected, rest)
            return render(snap, rest)

        app.overlay.render = tagged_render


def stats(values) -> str:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], float)
    if v.size == 0:
        return "n/a"
    return f"{np.median(v):.0f} / {np.percentile(v, 95):.0f} ms (n={v.size}, max {v.max():.0f})"


class Page:
    """One browser tab on the app, with the page-side stamps and their server-side matches."""

    def __init__(self, browser, url: str, viewport: str, log: ServerLog, app, hide_3d: bool = False) -> None:
        vw, vh = (int(v) for v in viewport.split("x"))
        self.page = browser.new_page(viewport={"width": vw, "height": vh})
        self.log, self.app = log, app
        self.page.goto(url)
        self.page.get_by_text("Use in optimisation").wait_for(timeout=60_000)
        for close in self.page.locator(".mantine-Notification-root button").all():
            close.click()  # viser's "WebGL in software mode" notice may lie over the tabs
        self.page.get_by_role("tab", name="Seed").click()
        self.page.get_by_text("included scenes:").wait_for(timeout=60_000)
        if hide_3d:
            self.page.add_style_tag(content="canvas { display: none !important; }")
        self.settle()
        assert self.page.evaluate(OBSERVE), "score readout element not found"
        self.origin = self.page.evaluate("() => performance.timeOrigin")

    def settle(self, changes: int | None = None, extra: float = 0.4) -> None:
        """Wait until ``changes`` slider changes reached the server (if given) and the page has
        painted the frame at rest of the current state; then ``extra`` s more (readout, table)."""
        deadline = time.monotonic() + 30
        while changes is not None and len(self.log.changes) < changes and time.monotonic() < deadline:
            time.sleep(0.01)
        version = self.app.state.snapshot().version
        while time.monotonic() < deadline:
            painted = self.page.evaluate("() => window.__b ? window.__b.frames.map(f => [f[0], f[3]]) : null")
            if painted is None:  # not observing yet: the server's frame at rest will do
                if self.app.views.overlay_worker.wait_idle(0) and self.app.overlay.rest_frame:
                    break
            elif any((f := self.sent(sha, t)) is not None and f[3] and f[1] >= version for t, sha in painted):
                break
            time.sleep(0.03)
        self.app.views.mi_worker.wait_idle(60)
        time.sleep(extra)

    def focus_slider(self) -> None:
        label = self.page.locator("label", has_text="yaw (°)").first.get_attribute("for")
        self.page.locator(f"[id='{label}']").get_by_role("slider").focus()

    def data(self) -> tuple[list, list, list, list]:
        d = self.page.evaluate("() => { const b = window.__b; const out = [b.inputs, b.frames, b.readouts, b.long];"
                               " window.__b.inputs = []; window.__b.frames = []; window.__b.readouts = [];"
                               " window.__b.long = []; return out; }")
        return d[0], d[1], d[2], d[3]

    def sent(self, sha: str, before: float) -> tuple | None:
        """The server's last sending of these bytes before page time ``before``."""
        return next((r for r in reversed(self.log.frames.get(sha, [])) if r[0] - self.origin <= before), None)

    def frames(self, raw: list) -> list[dict]:
        """Painted frames, in page time, with the server's record of each."""
        out = []
        for t_src, t_dec, t_paint, sha in raw:
            sent = self.sent(sha, t_src)
            out.append(dict(src=t_src, dec=t_dec, paint=t_paint, sent=None if sent is None else sent[0] - self.origin,
                            version=-1 if sent is None else sent[1], scene=-1 if sent is None else sent[2],
                            rest=bool(sent and sent[3]), bytes=0 if sent is None else sent[4]))
        return sorted(out, key=lambda f: f["paint"])


def first(frames: list[dict], t: float, pred=lambda f: True) -> dict | None:
    return next((f for f in frames if f["paint"] > t and pred(f)), None)


def change_after(p: Page, changes: list[tuple[float, int]], t: float) -> tuple[float, int] | None:
    """The first slider change the server received after the page's input at ``t`` (page time,
    server stamps are epoch ms: one machine, one clock): (received, state version)."""
    return next(((r - p.origin, v) for r, v in changes if r - p.origin >= t), None)


def steps(p: Page, presses: int) -> dict:
    """One press, then rest (the page painted the frame at rest), ``presses`` times."""
    p.focus_slider()
    p.data()
    n0 = len(p.log.changes)
    for i in range(presses):
        p.page.keyboard.press("ArrowRight" if i % 2 == 0 else "ArrowLeft")
        p.settle(n0 + i + 1)
    inputs, raw, readouts, long = p.data()
    frames, changes = p.frames(raw), p.log.changes[n0:]
    first_change, rest, readout, legs = [], [], [], []
    for t in inputs:
        f = first(frames, t)
        first_change.append(None if f is None else f["paint"] - t)
        ro = next((x for x in readouts if x > t), None)
        readout.append(None if ro is None else ro - t)
        got = change_after(p, changes, t)
        if got is None:
            continue
        recv, v = got
        r = first(frames, t, lambda f: f["rest"] and f["version"] >= v)
        rest.append(None if r is None else r["paint"] - t)
        f = first(frames, t, lambda f: f["version"] >= v)
        if f is not None and f["sent"] is not None:
            legs.append((recv - t, f["sent"] - recv, f["src"] - f["sent"], f["dec"] - f["src"], f["paint"] - f["dec"]))
    return dict(first=first_change, rest=rest, readout=readout, legs=legs, long=(len(long), sum(d for _, d in long)))


def held_key(p: Page, presses: int, repeat_ms: float) -> dict:
    """A key held down: inputs every ``repeat_ms``; each input -> the first painted frame showing it."""
    p.focus_slider()
    p.data()
    n0 = len(p.log.changes)
    for i in range(presses):
        p.page.keyboard.down("ArrowRight" if (i // 15) % 2 == 0 else "ArrowLeft")
        time.sleep(repeat_ms / 1000.0)
    p.page.keyboard.up("ArrowRight")
    p.page.keyboard.up("ArrowLeft")
    time.sleep(0.5)
    p.settle(extra=1.0)
    inputs, raw, _, long = p.data()
    frames, changes = p.frames(raw), p.log.changes[n0:]
    lat = []
    for t in inputs:
        got = change_after(p, changes, t)
        f = None if got is None else first(frames, t, lambda f: f["version"] >= got[1])
        lat.append(None if f is None else f["paint"] - t)
    kb = [f["bytes"] / 1000 for f in frames if f["bytes"]]
    return dict(lat=lat, kb=kb, frames=len(frames), inputs=len(inputs), changes=len(changes),
                long=(len(long), sum(d for _, d in long)))


def scene_switch(p: Page, n_scenes: int, clicks: int) -> list[float]:
    page = p.page
    page.get_by_role("tab", name="Scenes").click()
    page.get_by_role("cell", name="scene_000").first.wait_for(timeout=30_000)
    rng = np.random.default_rng(0)
    out = []
    current = p.app.state.snapshot().selected
    for k in rng.choice([i for i in range(n_scenes) if i != current], size=min(clicks, n_scenes - 1), replace=False):
        cell = page.locator("td", has_text=f"scene_{int(k):03d}").first
        cell.scroll_into_view_if_needed()
        p.settle()
        p.data()
        t_click = page.evaluate("() => performance.now()")
        cell.dispatch_event("click")
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            f = first(p.frames(page.evaluate("() => window.__b.frames")), t_click, lambda f: f["scene"] == int(k))
            if f is not None:
                out.append(f["paint"] - t_click)
                break
            time.sleep(0.02)
    page.get_by_role("tab", name="Seed").click()
    return out


def run_one(browser, app, log: ServerLog, url: str, viewport: str, delay: float, args) -> None:
    rtt = 2 * delay
    where = "direct" if delay == 0 else f"through the proxy, {delay:g} ms each way (RTT {rtt:g} ms)"
    print(f"\n== {viewport}, {where}", flush=True)
    p = Page(browser, url, viewport, log, app, args.hide_3d)
    parts = args.parts.split(",")
    try:
        if "steps" in parts:
            report_steps(p, args)
        if "held" in parts:
            report_held(p, args)
        if "switch" in parts:
            sw = scene_switch(p, len(app.state.scene_names), args.clicks)
            print(f"  scene table row click -> that scene's overlay painted: {stats(sw)}")
    finally:
        p.page.close()


def report_steps(p: Page, args) -> None:
    s = steps(p, args.presses)
    print(f"  key press -> first overlay change painted: {stats(s['first'])}")
    print(f"  key press -> frame at rest painted:        {stats(s['rest'])}")
    print(f"  key press -> score readout painted:        {stats(s['readout'])}")
    if s["legs"]:
        m = np.median(np.array(s["legs"]), axis=0)
        print(f"  legs (median): key -> server got it {m[0]:.0f} ms; -> frame handed to viser {m[1]:.0f} ms; "
              f"-> src set in the page {m[2]:.0f} ms; -> decoded {m[3]:.0f} ms; -> painted {m[4]:.0f} ms")
    elif not s["matched"]:
        print("  (inputs and server changes did not pair up: no legs)")
    print(f"  page long tasks during the presses: {s['long'][0]}, {s['long'][1]:.0f} ms in all")


def report_held(p: Page, args) -> None:
    h = held_key(p, args.presses * 2, args.repeat_ms)
    kb = np.array(h["kb"]) if h["kb"] else np.zeros(1)
    print(f"  held key (a repeat every {args.repeat_ms:g} ms): input -> a frame showing it painted: "
          f"{stats(h['lat'])}; {h['frames']} frames for {h['inputs']} inputs, {kb.mean():.1f} KB per update "
          f"(max {kb.max():.1f}); long tasks {h['long'][0]}, {h['long'][1]:.0f} ms")
    if h["changes"] != h["inputs"]:
        print(f"  ({h['inputs']} key events, {h['changes']} changes reached the server)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=40)
    parser.add_argument("--points", type=int, default=75_000)
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    parser.add_argument("--presses", type=int, default=20)
    parser.add_argument("--clicks", type=int, default=8)
    parser.add_argument("--repeat-ms", type=float, default=33.0, help="key auto-repeat interval of a held key")
    parser.add_argument("--viewports", default="1366x768,1920x1080")
    parser.add_argument("--delays", default="0,40", help="ms each way through delay_proxy.py; 0 = direct")
    parser.add_argument("--parts", default="steps,held,switch", help="which of steps,held,switch to run")
    parser.add_argument("--hide-3d", action="store_true", help="diagnosis: no 3D view in the page (display: none)")
    args = parser.parse_args()

    from playwright.sync_api import sync_playwright

    from l2e_studio.app.server import build_app

    t0 = time.perf_counter()
    scene_set = build_scene_set(args.scenes, args.points, args.width, args.height)
    port = free_port()
    app = build_app(scene_set, port=port, out_dir=scene_set.root / "results")
    print(f"{args.scenes} scenes of {args.width}x{args.height}, {args.points} points; app up in "
          f"{time.perf_counter() - t0:.1f} s; {threading.active_count()} threads", flush=True)
    log = ServerLog(app)
    proxies: dict[float, DelayProxy] = {}
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            for viewport in args.viewports.split(","):
                for delay in (float(d) for d in args.delays.split(",")):
                    url = app.url
                    if delay > 0:
                        if delay not in proxies:
                            proxies[delay] = DelayProxy(("127.0.0.1", port), delay)
                        url = f"http://127.0.0.1:{proxies[delay].port}"
                    run_one(browser, app, log, url, viewport, delay, args)
            browser.close()
        srv = np.array(app.views.overlay_seconds[-100:]) * 1e3
        print(f"\nserver render+encode per frame: median {np.median(srv):.0f} ms, p95 {np.percentile(srv, 95):.0f} ms")
    finally:
        for proxy in proxies.values():
            proxy.stop()
        app.stop()
    import resource
    print(f"peak memory of the app's process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
