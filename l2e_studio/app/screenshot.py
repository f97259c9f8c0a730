"""Take the README screenshot with a real browser: ``python -m l2e_studio.app.screenshot``.

Serves the embedded sample scenes, drives headless Chromium (Debian's, through Playwright, a
test dependency) through one optimisation, accepts the result and saves the page as a
palette PNG (``assets/screenshot.png`` by default, kept under 300 KB).
"""

from __future__ import annotations

import argparse
import socket
import tempfile
import time
from pathlib import Path

from ..samples import sample_scenes_dir
from ..scenes import load_scene_folder
from .server import build_app

CHROMIUM_ARGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(condition, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError("the app did not get there in time")
        time.sleep(0.05)


def _close_notifications(page) -> None:
    for button in page.locator(".mantine-Notification-root button").all():
        try:
            button.click(timeout=1000)
        except Exception:  # already gone
            pass


def take(out: Path, scenes: Path, chromium: str, width: int = 1600, height: int = 900) -> Path:
    from playwright.sync_api import sync_playwright

    scene_set = load_scene_folder(scenes)
    with tempfile.TemporaryDirectory(prefix="l2e_shot_") as tmp:
        app = build_app(scene_set, port=free_port(), out_dir=Path(tmp) / "results")
        try:
            with sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
                page = browser.new_page(viewport={"width": width, "height": height})
                page.goto(app.url)
                page.get_by_text("Use in optimisation").wait_for(timeout=30_000)
                page.get_by_role("tab", name="Optimise").click()
                page.get_by_role("button", name="Start").click()
                _wait(lambda: app.state.snapshot().run.status == "done", 300)
                page.get_by_role("tab", name="Result").click()
                page.get_by_role("button", name="Accept as seed").click()
                _wait(lambda: app.views.overlay_worker.wait_idle(1) and app.views.mi_worker.wait_idle(1), 30)
                page.get_by_role("tab", name="Optimise").click()
                page.get_by_text("Finished").first.wait_for()
                time.sleep(1.0)
                _close_notifications(page)
                time.sleep(1.0)
                raw = Path(tmp) / "raw.png"
                page.screenshot(path=str(raw))
                browser.close()
            _save_small_png(raw, out)
        finally:
            app.stop()
    return out


def _save_small_png(raw: Path, out: Path, limit: int = 300_000) -> None:
    """A 256-colour PNG (the UI has few colours); shrinks the image if still over ``limit``."""
    from PIL import Image

    img = Image.open(raw).convert("RGB")
    out.parent.mkdir(parents=True, exist_ok=True)
    for scale in (1.0, 0.9, 0.8, 0.7):
        im = img if scale == 1.0 else img.resize((round(img.width * scale), round(img.height * scale)), Image.LANCZOS)
        im.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(out, optimize=True)
        if out.stat().st_size <= limit:
            return


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[2] / "assets" / "screenshot.png")
    parser.add_argument("--scenes", type=Path, default=None)
    parser.add_argument("--chromium", default="/usr/bin/chromium")
    args = parser.parse_args()
    path = take(args.out, args.scenes or sample_scenes_dir(), args.chromium)
    print(f"wrote {path} ({path.stat().st_size // 1024} KiB)")


if __name__ == "__main__":
    main()
