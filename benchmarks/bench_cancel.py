"""Cancel -> stopped, for every optimiser, at N full-size scenes (default 40) with five tabs open.

A real app (viser server in this process) and five headless Debian Chromium tabs (Playwright),
all on the Optimise tab. For each optimiser and each moment (seconds after Start, so that the
cancel lands in different phases: the first stage, a stage change, the last stage), the run is
started from one tab and cancelled from another by a click; the page stamps the click, and the
run counts as stopped when the server's state says "cancelled" and the Start button is back.

Run: ``python benchmarks/bench_cancel.py [--scenes 40] [--at 0.5,1.5,3.0]``.
Target (issue 10): stopped <= 1 s after the click, every optimiser, five tabs.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_browser_overlay import CHROMIUM, build_scene_set  # noqa: E402

from l2e_studio.app.screenshot import CHROMIUM_ARGS, free_port  # noqa: E402
from l2e_studio.calibrate import METHODS  # noqa: E402

STAMP_CLICKS = """() => document.addEventListener('click', () => {
    window.__clicked = performance.timeOrigin + performance.now(); }, true)"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=40)
    parser.add_argument("--tabs", type=int, default=5)
    parser.add_argument("--at", default="0.5,1.5,3.0", help="seconds after Start at which to cancel")
    parser.add_argument("--methods", default=",".join(METHODS))
    args = parser.parse_args()
    moments = [float(x) for x in args.at.split(",")]

    from playwright.sync_api import sync_playwright

    from l2e_studio.app.server import build_app

    scene_set = build_scene_set(args.scenes, 75_000, 1280, 720)
    app = build_app(scene_set, port=free_port(), out_dir=scene_set.root / "results")
    print(f"{args.scenes} full-size scenes, {args.tabs} tabs", flush=True)
    worst = {}
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            pages = []
            for _ in range(args.tabs):
                page = browser.new_context(viewport={"width": 1366, "height": 768}).new_page()
                page.goto(app.url)
                page.get_by_role("tab", name="Optimise").click()
                page.get_by_role("button", name="Start").wait_for(timeout=60_000)
                pages.append(page)
            starter, canceller = pages[0], pages[-1]
            canceller.evaluate(STAMP_CLICKS)
            for method in args.methods.split(","):
                app.optimise.method.value = method
                times = []
                for at in moments:
                    app.wait_run(120)
                    starter.get_by_role("button", name="Start").click()
                    t_start = time.monotonic()
                    while not app.state.snapshot().run.active:
                        time.sleep(0.005)
                    time.sleep(max(0.0, at - (time.monotonic() - t_start)))
                    if not app.state.snapshot().run.active:
                        print(f"  {method}: the run ended before {at:.1f} s; nothing to cancel")
                        continue
                    snap = app.state.snapshot().run
                    canceller.get_by_role("button", name="Cancel").click()
                    while app.state.snapshot().run.status != "cancelled":
                        time.sleep(0.002)
                    stopped = time.time()
                    clicked = canceller.evaluate("() => window.__clicked") / 1000.0
                    times.append(stopped - clicked)
                    print(f"  {method}: cancelled {at:.1f} s into the run (stage {snap.stage + 1}/{snap.stages}, "
                          f"{snap.evaluations} evaluations): stopped {1000 * (stopped - clicked):.0f} ms after the click",
                          flush=True)
                    app.discard_result()
                if times:
                    worst[method] = max(times)
            browser.close()
    finally:
        app.stop()
    for method, t in worst.items():
        print(f"{method}: worst cancel -> stopped {1000 * t:.0f} ms ({'ok' if t <= 1.0 else 'OVER 1 s'})")


if __name__ == "__main__":
    main()
