"""Figures for the report: overlays with OpenCV, plots with matplotlib (Agg, no display)."""

from __future__ import annotations

import base64
import io

import cv2
import numpy as np

from ..camera import CameraModel
from ..drawing import depth_colors, disc_size, draw_points, point_table
from ..geometry import Extrinsic, in_image, project_points
from . import AXES, UNITS


def data_uri_png(rgb: np.ndarray) -> str:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return "data:image/png;base64," + base64.b64encode(buf.tobytes()).decode()


def data_uri_jpeg(rgb: np.ndarray, quality: int = 80) -> str:
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR),
                           [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode()


def display_factor(camera: CameraModel) -> int:
    """Small maps are drawn enlarged (nearest neighbour) so that points and edges stay visible."""
    return max(1, int(round(800 / camera.width)))


#: CSS px an overlay figure is shown at in the report (two per row): discs are sized for it.
SHOWN_PX = 520


def overlay(event_map: np.ndarray, points: np.ndarray, intensity: np.ndarray, ext: Extrinsic, camera: CameraModel,
            clip: float = 127.0, point_px: float = 2.0, map_kind: str = "events",
            box: tuple[int, int, int, int] | None = None, factor: int = 1) -> np.ndarray:
    """The map in grey with the lidar points projected at ``ext`` as discs ``point_px`` across
    when the figure is shown :data:`SHOWN_PX` wide, each with a dark outline; coloured by depth
    on camera images (``map_kind="image"``), by intensity on event maps. Maps narrower than
    800 px are enlarged by :func:`display_factor` first. ``box`` (x0, y0, w, h in map pixels):
    only that window, enlarged ``factor`` times more, the points drawn afresh at the same size
    on screen (a crop of the full figure would enlarge them too)."""
    f = display_factor(camera) * factor
    x0, y0, w, h = box if box is not None else (0, 0, camera.width, camera.height)
    m = np.clip(np.asarray(event_map, np.float32), 0, clip)
    hi = float(np.percentile(m, 99.5)) or 1.0  # of the whole map: a crop reads as the full figure does
    grey = (np.clip(m[y0:y0 + h, x0:x0 + w] / hi, 0, 1) * 200).astype(np.uint8)  # keep the map darker than the points
    if f > 1:
        grey = cv2.resize(grey, (w * f, h * f), interpolation=cv2.INTER_NEAREST)
    img = cv2.cvtColor(grey, cv2.COLOR_GRAY2RGB)
    cam_pts = ext.transform(np.asarray(points, np.float64))
    front = cam_pts[:, 2] > 0.05
    uv, _ = project_points(cam_pts[front], camera)
    inside = in_image(uv, camera)
    uv = (uv[inside] - (x0, y0) + 0.5) * f - 0.5
    depth = cam_pts[front][inside, 2]
    if map_kind == "events":
        colors = point_table()[np.clip(np.asarray(intensity, np.float64)[front][inside], 0, 255).astype(np.uint8)]
    else:
        colors = depth_colors(depth)
    per_screen = img.shape[1] / SHOWN_PX
    return draw_points(img, uv, colors, disc_size(point_px, per_screen), 0.85, depth, disc_size(1, per_screen))


def crop_factor(camera: CameraModel, box: tuple[int, int, int, int]) -> int:
    """How much more than the full figure a crop ``box`` (x0, y0, w, h) is enlarged: at least 2x,
    and enough to make it as wide as the full figure. A page shows an image no wider than it is,
    so a narrower crop would show its discs smaller than the full figure's, 1 px cores whose
    colour the dark outline swallows (a 192 px crop of a 640 px map at 2x: 384 px)."""
    return max(2, -(-int(camera.width) // max(int(box[2]), 1)))


def crop_box(event_map: np.ndarray, frac: float = 0.3) -> tuple[int, int, int, int]:
    """(x0, y0, w, h) of the ``frac``-sized window with the most event structure (gradient energy)."""
    m = cv2.GaussianBlur(np.asarray(event_map, np.float32), (0, 0), 3.0)  # structure, not pixel noise
    H, W = m.shape
    w, h = max(8, int(W * frac)), max(8, int(H * frac))
    g = np.abs(cv2.Sobel(m, cv2.CV_32F, 1, 0)) + np.abs(cv2.Sobel(m, cv2.CV_32F, 0, 1))
    box = cv2.boxFilter(g, -1, (w, h), normalize=False, borderType=cv2.BORDER_CONSTANT)
    box[: h // 2, :] = -1
    box[H - (h - h // 2):, :] = -1
    box[:, : w // 2] = -1
    box[:, W - (w - w // 2):] = -1
    cy, cx = np.unravel_index(int(np.argmax(box)), box.shape)
    return int(cx - w // 2), int(cy - h // 2), w, h


def _fig_uri(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def landscape_figure(sweeps: list, label: str = "MI (nats)") -> str:
    plt = _plt()
    fig, axs = plt.subplots(2, 3, figsize=(11, 5.5))
    for ax, s in zip(axs.ravel(), sweeps):
        unit = "m" if s.axis in AXES[:3] else "deg"
        ax.plot(s.offsets, s.mi, "o-", ms=3)
        ax.axvline(0, color="k", lw=0.8, ls="--")
        ax.set_title(f"{s.axis}: half width {s.half_width():.3g} {unit}", fontsize=9)
        ax.set_xlabel(f"offset ({unit})")
        ax.set_ylabel(label)
    fig.tight_layout()
    return _fig_uri(fig)


def landscape2d_figure(sw, label: str = "MI (nats)") -> str:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    oa, ob = sw.offsets
    im = ax.imshow(sw.mi, origin="lower", aspect="auto", extent=[ob[0], ob[-1], oa[0], oa[-1]], cmap="viridis")
    ax.plot([0], [0], "r+", ms=12)
    ax.set_xlabel(f"{sw.axes[1]} offset ({'m' if sw.axes[1] in AXES[:3] else 'deg'})")
    ax.set_ylabel(f"{sw.axes[0]} offset ({'m' if sw.axes[0] in AXES[:3] else 'deg'})")
    fig.colorbar(im, ax=ax, label=label)
    return _fig_uri(fig)


def scatter_figure(seeds: np.ndarray, results: np.ndarray, methods: list[str]) -> str:
    """Result against seed per parameter (the paper's noise experiment)."""
    plt = _plt()
    fig, axs = plt.subplots(2, 3, figsize=(11, 6))
    for k, ax in enumerate(axs.ravel()):
        for m in sorted(set(methods)):
            sel = np.array([mm == m for mm in methods])
            ax.scatter(seeds[sel, k], results[sel, k], s=12, label=m)
        ax.axhline(0, color="k", lw=0.8, ls="--")
        ax.set_title(AXES[k], fontsize=9)
        ax.set_xlabel(f"seed ({UNITS[k]})")
        ax.set_ylabel(f"result ({UNITS[k]})")
    axs[0, 0].legend(fontsize=7)
    fig.tight_layout()
    return _fig_uri(fig)


def scene_count_figure(counts: list[int], stds: np.ndarray) -> str:
    plt = _plt()
    fig, axs = plt.subplots(1, 2, figsize=(10, 4))
    for k in range(6):
        ax = axs[0] if k < 3 else axs[1]
        ax.plot(counts, stds[:, k], "o-", label=AXES[k])
    for ax, unit in zip(axs, ("mm", "deg")):
        ax.set_xlabel("scenes used")
        ax.set_ylabel(f"std ({unit})")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.legend(fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return _fig_uri(fig)


def target_residuals_figure(frames: list[dict]) -> str:
    """Per-frame residuals of a checkerboard result (the result file's ``target.frames``): the
    lidar board points' RMS distance to the camera's board plane and the edge points' to the
    board's outline (mm; frames left out hatched grey), and each detection's reprojection error (px)."""
    plt = _plt()
    names = [str(f.get("name")) for f in frames]
    x = np.arange(len(frames))
    val = lambda f, k, s=1.0: np.nan if f.get(k) is None else float(f[k]) * s  # noqa: E731
    plane = np.array([val(f, "plane_rms_m", 1000.0) for f in frames])
    edge = np.array([val(f, "edge_rms_m", 1000.0) for f in frames])
    rep = np.array([val(f, "reprojection_px") for f in frames])
    used = np.array([bool(f.get("used")) for f in frames])
    fig, (a0, a1) = plt.subplots(2, 1, figsize=(max(6.0, 0.45 * len(frames) + 2), 5.5), sharex=True)
    w = 0.4
    for sel, style in ((used, {}), (~used, {"color": "#bbb", "hatch": "//"})):
        a0.bar(x[sel] - w / 2, plane[sel], w, label="plane RMS" if sel is used else None,
               **({"color": "#1c7ed6"} | style))
        a0.bar(x[sel] + w / 2, edge[sel], w, label="edge RMS" if sel is used else None,
               **({"color": "#e8590c"} | style))
    a0.set_ylabel("lidar residual (mm)")
    a0.legend(fontsize=8)
    a0.grid(True, axis="y", alpha=0.3)
    a1.bar(x, rep, 0.6, color=np.where(used, "#2b8a3e", "#bbb"))
    a1.set_ylabel("reprojection (px)")
    a1.grid(True, axis="y", alpha=0.3)
    a1.set_xticks(x)
    a1.set_xticklabels(names, rotation=60, ha="right", fontsize=7)
    for k in np.flatnonzero(~np.array([bool(f.get("detected")) for f in frames])):
        a1.text(k, 0, "no board", rotation=90, ha="center", va="bottom", fontsize=7, color="#c92a2a")
    fig.tight_layout()
    return _fig_uri(fig)
