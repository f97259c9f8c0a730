"""Screenshots of the workbench at the two layouts users have, and of the overlay inspection.

    python benchmarks/shots_layout.py [--scenes DIR] [--out benchmarks/out/shots]

Serves DIR (default: the 40 full-size synthetic scenes of ``bench_engine.py``) in a real app,
opens it in headless Debian Chromium at 1366x768 and at 1920x1080, and saves: the whole page;
the page with the overlay zoomed 2x around a clicked point; the edge view. For looking at, not
for asserting (the browser tests assert the behaviour).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_engine import dataset  # noqa: E402

from l2e_studio.app.screenshot import CHROMIUM_ARGS, _close_notifications, free_port  # noqa: E402
from l2e_studio.app.server import build_app  # noqa: E402
from l2e_studio.scenes import load_scene_folder  # noqa: E402

LAYOUTS = ((1366, 768), (1920, 1080))


def settle(app) -> None:
    for worker in (app.views.overlay_worker, app.views.mi_worker, app.views.compare_worker, app.views.scene_3d_worker):
        worker.wait_idle(30)
    time.sleep(1.5)  # the frame at rest and the table follow 0.3 s after the last change


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out" / "shots")
    args = parser.parse_args()
    from playwright.sync_api import sync_playwright

    scene_set = load_scene_folder(args.scenes or dataset(40))
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="l2e_shots_") as tmp:
        app = build_app(scene_set, port=free_port(), out_dir=Path(tmp) / "results")
        try:
            with sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
                for w, h in LAYOUTS:
                    page = browser.new_page(viewport={"width": w, "height": h})
                    page.goto(app.url)
                    page.get_by_text("Use in optimisation").wait_for(timeout=60_000)
                    settle(app)
                    _close_notifications(page)
                    page.screenshot(path=str(args.out / f"layout_{w}x{h}.png"))
                    app.overlay.centre = (scene_set.camera.width * 0.45, scene_set.camera.height * 0.5)
                    app.overlay.zoom.value = "2x"
                    settle(app)
                    page.screenshot(path=str(args.out / f"zoom2x_{w}x{h}.png"))
                    app.overlay.zoom.value = "fit"
                    app.overlay.view.value = "edges"
                    settle(app)
                    page.screenshot(path=str(args.out / f"edges_{w}x{h}.png"))
                    app.overlay.view.value = "overlay"
                    page.close()
                browser.close()
        finally:
            app.stop()
    print(f"wrote {len(LAYOUTS) * 3} screenshots to {args.out}")


if __name__ == "__main__":
    main()
