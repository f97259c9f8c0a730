"""Synthetic calibration scenes with a known answer.

A cartoon of the paper's setup: a MEMS lidar (RS-LiDAR-M1: 120 x 25 deg, ~75k points per scan)
and an event camera (Prophesee GEN4.1: 1280 x 720, 63 x 38 deg) on one rig, in a garage
(:mod:`l2e_studio.synth.layout`). For each scene:

* the lidar casts a jittered zig-zag raster of rays into the world; a return is the first hit,
  with Gaussian range noise, and an intensity (calibrated reflectivity, 0..255) that follows the
  surface reflectance and, mildly, the incidence angle;
* every pulse direction fires ``pulses`` times in the 3 s window. Where the camera sees the laser
  spot (the TRUE hit point, projected with the TRUE extrinsic and lens distortion, and not
  occluded from the camera centre), each pixel of the spot's small blur triggers events at a
  rate that grows, saturating, with the light it receives (reflectance x cos(view angle) /
  distance^2; retro-reflectors send far more); counts are Poisson-sampled;
* background noise events, hot pixels and dead pixels are added, and the map is stored 8-bit.

:func:`write_dataset` writes a scene folder in the reference code's layout plus ``camera.yaml``
(ours) and ``truth.yaml`` (the true ``T_cam_lidar``); the seed written is the truth perturbed by
``seed_error_deg`` / ``seed_error_m`` in a random direction.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from ..atomic import atomic_write_bytes
from ..camera import CameraModel
from ..errors import InputError
from ..geometry import LIDAR_TO_CAMERA_AXES, Extrinsic, in_image, project_points
from .layout import make_layout
from .lidars import LIDARS, ring_directions
from .realism import SKY_RANGE_M, TRAPS, camera_image, event_traps, first_returns, sky_mask
from .world import cast, surface


@dataclass(frozen=True)
class SynthConfig:
    """Everything that shapes a synthetic dataset. Defaults: the paper's sensors, 40 scenes."""

    n_scenes: int = 40
    width: int = 1280
    height: int = 720
    points_per_scan: int = 75_000
    lidar_hfov_deg: float = 120.0
    lidar_vfov_deg: float = 25.0
    camera_hfov_deg: float = 63.0
    distortion: bool = True
    seed: int = 0
    seed_error_deg: float = 2.0
    seed_error_m: float = 0.05
    camera_offset_m: tuple[float, float] = (0.05, 0.15)  # range of the lidar-to-camera distance
    max_range_m: float = 80.0
    range_noise_m: float = 0.015
    intensity_noise: float = 2.0
    pulses: int = 30  # firings of each direction in the 3 s window (10 Hz)
    events_per_pulse: float = 4.0  # events a fully lit pixel gives per pulse (ON + OFF + ringing)
    spot_threshold: float = 0.012  # light (rho / m^2) that lights a pixel to 63% of its peak rate
    psf_sigma_px: float = 1.0  # blur of the laser spot on the sensor
    background_rate: float = 0.15  # noise events per pixel in the window
    hot_pixels: int = 300
    dead_pixels: int = 40
    checkerboard_fraction: float = 0.4  # share of scenes with calibration targets near the rig
    falloff_exponent: float = 2.0  # spot light at the camera ~ 1 / distance**falloff_exponent
    map_kind: str = "events"  # "events": accumulated laser-return events; "image": a grey camera image
    realism: bool = False  # every failure mode of real data for the map kind (realism.TRAPS)
    traps: tuple[str, ...] = ()  # or some of them, by name
    intensity_scale: float = 1.0  # < 1: a dim cloud (0.055 gives the 0..14 intensities of a sparse-cloud trap)
    #: a spinning lidar's rings (a name of ``lidars.LIDARS``: vlp16, hdl32, ...) within the lidar's
    #: horizontal field of view, instead of the MEMS raster (``points_per_scan`` then unused)
    lidar: str | None = None
    #: revolutions of that lidar accumulated into each scene's cloud, as a static rig's recording
    #: is: each at a firing phase of its own (a free-running lidar: the sweeps interleave), or at
    #: one (``lidar_phase_locked``: the same azimuths each time, a return per revolution)
    lidar_sweeps: int = 1
    lidar_phase_locked: bool = False

    def __post_init__(self) -> None:
        if self.n_scenes < 1 or self.width < 16 or self.height < 16 or self.points_per_scan < 100:
            raise ValueError("need >= 1 scene, a map of at least 16x16 and >= 100 points per scan")
        if not (0 < self.lidar_hfov_deg < 180 and 0 < self.lidar_vfov_deg < 90 and 0 < self.camera_hfov_deg < 170):
            raise ValueError("fields of view out of range")
        if self.seed_error_deg < 0 or self.seed_error_m < 0:
            raise ValueError("seed errors must be >= 0")
        if not 0 <= self.camera_offset_m[0] <= self.camera_offset_m[1]:
            raise ValueError("camera_offset_m must be an increasing (min, max) pair of distances")
        if self.map_kind not in TRAPS:
            raise ValueError(f"map_kind must be one of {', '.join(TRAPS)}")
        unknown = set(self.traps) - set(TRAPS[self.map_kind])
        if unknown:
            raise ValueError(f"unknown {self.map_kind} trap(s) {', '.join(sorted(unknown))}; "
                             f"expected some of {', '.join(TRAPS[self.map_kind])}")
        if not 0 < self.intensity_scale <= 1:
            raise ValueError("intensity_scale must be in (0, 1]")
        if self.lidar is not None and self.lidar not in LIDARS:
            raise ValueError(f"lidar must be one of {', '.join(LIDARS)}")
        if self.lidar_sweeps < 1:
            raise ValueError("lidar_sweeps must be >= 1")

    @property
    def active_traps(self) -> tuple[str, ...]:
        """The failure modes this dataset reproduces (all of the map kind's with ``realism``)."""
        return TRAPS[self.map_kind] if self.realism else tuple(self.traps)


#: The embedded sample (``assets/sample``): six small scenes.
SAMPLE_CONFIG = SynthConfig(n_scenes=6, width=640, height=360, points_per_scan=20_000, seed=7)


def make_rig(config: SynthConfig) -> tuple[CameraModel, Extrinsic, Extrinsic]:
    """The camera, the true ``T_cam_lidar`` and the seed (truth perturbed), all from ``config.seed``."""
    rng = np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(0,)))
    w, h = config.width, config.height
    f = (w / 2) / np.tan(np.radians(config.camera_hfov_deg) / 2)
    cx = (w - 1) / 2 + rng.uniform(-0.01, 0.01) * w
    cy = (h - 1) / 2 + rng.uniform(-0.01, 0.01) * h
    K = np.array([[f, 0, cx], [0, f * (1 + rng.uniform(-1e-3, 1e-3)), cy], [0, 0, 1]])
    D = np.array([-0.08, 0.02, 4e-4, -3e-4, 0.0]) if config.distortion else np.zeros(5)
    camera = CameraModel(K, w, h, D)

    mount = Rotation.from_euler("xyz", rng.uniform(-3, 3, 3), degrees=True).as_matrix()
    R = LIDAR_TO_CAMERA_AXES @ mount  # camera axes from lidar axes, then a small mounting error
    offset = rng.normal(size=3)
    offset *= rng.uniform(*config.camera_offset_m) / np.linalg.norm(offset)  # camera centre in the lidar frame
    truth = Extrinsic(Rotation.from_matrix(R).as_rotvec(), -R @ offset)
    seed = perturb(truth, config.seed_error_deg, config.seed_error_m, rng)
    return camera, truth, seed


def perturb(truth: Extrinsic, error_deg: float, error_m: float, rng: np.random.Generator) -> Extrinsic:
    """``truth`` moved by exactly ``error_deg`` and ``error_m`` in random directions (camera frame)."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    step = rng.normal(size=3)
    step /= np.linalg.norm(step)
    return truth.perturbed(step * error_m, axis * np.radians(error_deg))


def lidar_directions(config: SynthConfig, rng: np.random.Generator) -> np.ndarray:
    """Unit ray directions (lidar frame) of one scan: a jittered MEMS-like zig-zag raster, or
    the rings of ``config.lidar`` within the horizontal field of view."""
    if config.lidar is not None:
        spec = LIDARS[config.lidar]
        first = ring_directions(spec["elevations_deg"], spec["azimuth_step_deg"], rng, config.lidar_hfov_deg)[0]
        more = [first if config.lidar_phase_locked else
                ring_directions(spec["elevations_deg"], spec["azimuth_step_deg"], rng, config.lidar_hfov_deg)[0]
                for _ in range(config.lidar_sweeps - 1)]
        return np.concatenate([first, *more]) if more else first
    aspect = config.lidar_hfov_deg / config.lidar_vfov_deg
    n_h = max(2, int(round(np.sqrt(config.points_per_scan * aspect))))
    n_v = max(2, int(round(config.points_per_scan / n_h)))
    hf, vf = np.radians(config.lidar_hfov_deg), np.radians(config.lidar_vfov_deg)
    da, de = hf / n_h, vf / n_v
    az = (np.arange(n_h) + 0.5) * da - hf / 2
    el = (np.arange(n_v) + 0.5) * de - vf / 2
    A, E = np.meshgrid(az, el)
    # The mirror sweeps rows in a zig-zag: each row tilts by half a row over a 24 deg block.
    block = np.radians(24.0)
    E = E + 0.5 * de * (np.abs(((A + hf / 2) / block) % 2.0 - 1.0) - 0.5)
    A = A + rng.uniform(-0.25, 0.25, A.shape) * da
    E = E + rng.uniform(-0.25, 0.25, E.shape) * de
    A, E = A.ravel(), E.ravel()
    return np.column_stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)])


def _scene_rng(config: SynthConfig, index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(1, index)))


def make_scene(
    config: SynthConfig, index: int, truth: Extrinsic, camera: CameraModel
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scene ``index``: lidar points (N, 3) float32 (lidar frame, noisy ranges), intensity (N,)
    float32 0..255, and the accumulated event map (H, W) uint8."""
    rng = _scene_rng(config, index)
    checker = rng.random() < config.checkerboard_fraction
    half_view = np.radians(min(config.camera_hfov_deg, config.lidar_hfov_deg)) * 0.43
    layout = make_layout(rng, checker, view_half_angle=half_view)
    boxes = layout.boxes

    # --- lidar ----------------------------------------------------------------------------
    dirs_l = lidar_directions(config, rng)
    if "footprint" in config.active_traps:  # a beam, not a ray: the nearest surface across it
        hits, dirs_w = first_returns(boxes, layout.lidar_pos, dirs_l, layout.lidar_R, config.max_range_m)
    else:
        dirs_w = dirs_l @ layout.lidar_R.T
        hits = cast(boxes, layout.lidar_pos, dirs_w, config.max_range_m)
    ok = hits.index >= 0
    dirs_l, dirs_w = dirs_l[ok], dirs_w[ok]
    hits.t, hits.index = hits.t[ok], hits.index[ok]
    surf = surface(boxes, layout.lidar_pos, dirs_w, hits)
    cos_l = np.abs(np.einsum("ij,ij->i", surf.normals, dirs_w))
    diffuse = np.minimum(surf.rho, 1.0)
    retro = surf.rho > 1.0
    # weak returns (dark, grazing, far) are sometimes lost
    raw = diffuse * np.maximum(cos_l, 0.05) / np.maximum(hits.t, 1.0) ** 2
    returned = retro | (rng.random(raw.size) < 1.0 - np.exp(-raw / 2e-5))
    reflectivity = np.where(retro, 215.0 + 40.0 * (surf.rho - 1.15) / 0.3, 200.0 * diffuse * (0.45 + 0.55 * cos_l))
    reflectivity *= 1.0 - 0.002 * hits.t  # a mild range dependence left by the sensor's correction
    intensity = np.clip(np.round(config.intensity_scale * (reflectivity + rng.normal(0, config.intensity_noise, raw.size))), 0, 255)
    if "sky" in config.active_traps:
        # the sky returns nothing, and what lies just below it (far, weakly lit) returns dimly
        returned &= ~sky_mask(hits.t, surf.normals)
        intensity = np.where(hits.t > 0.5 * SKY_RANGE_M, np.round(0.3 * intensity), intensity)
    sigma_r = config.range_noise_m * (1.0 + hits.t / 40.0)
    ranges = hits.t + rng.normal(size=hits.t.size) * sigma_r
    points = dirs_l * ranges[:, None]

    # --- the camera: accumulated events of the laser spots, or a grey image of the world -------
    if config.map_kind == "image":
        event_map = camera_image(camera, truth, layout.lidar_R, layout.lidar_pos, boxes, config.active_traps, rng)
    else:
        true_lidar = dirs_l * hits.t[:, None]  # spots are where the pulses really hit
        event_map = _event_map(config, camera, truth, layout, boxes, true_lidar, surf, rng)

    return points[returned].astype(np.float32), intensity[returned].astype(np.float32), event_map


def _event_map(config, camera, truth, layout, boxes, true_lidar, surf, rng) -> np.ndarray:
    """Accumulated event counts (uint8) caused by the laser spots at ``true_lidar``."""
    w, h = camera.width, camera.height
    uv, front = project_points(truth.transform(true_lidar), camera)
    pad = 4
    vis = front & in_image(uv, camera, margin=-pad)
    idx = np.flatnonzero(vis)
    # is the spot seen from the camera centre, or hidden behind something?
    cam_w = layout.lidar_R @ truth.inverse().translation + layout.lidar_pos
    to_spot = surf.points[idx] - cam_w
    dist = np.linalg.norm(to_spot, axis=1)
    view = to_spot / dist[:, None]
    blocked = cast(boxes, cam_w, view, dist * (1 - 1e-7) - 1e-6).index >= 0
    idx, view, dist = idx[~blocked], view[~blocked], dist[~blocked]

    rho = surf.rho[idx]
    cos_c = np.abs(np.einsum("ij,ij->i", surf.normals[idx], view))
    gain = np.where(rho > 1.0, 12.0 * rho, rho)  # retro-reflectors shine back at the rig
    traps = config.active_traps
    falloff = config.falloff_exponent + (1.5 if "falloff" in traps else 0.0)
    light = gain * cos_c / dist**falloff * rng.uniform(0.8, 1.25)  # per-scene contrast sensitivity
    u, v = uv[idx, 0], uv[idx, 1]
    iu, iv = np.round(u).astype(np.int64), np.round(v).astype(np.int64)
    off = np.arange(-pad, pad + 1)
    ox, oy = np.meshgrid(off, off)
    px = iu[:, None] + ox.ravel()[None, :]
    py = iv[:, None] + oy.ravel()[None, :]
    r2 = (px - u[:, None]) ** 2 + (py - v[:, None]) ** 2
    lit = light[:, None] * np.exp(-r2 / (2 * config.psf_sigma_px**2))
    rate = config.pulses * config.events_per_pulse * -np.expm1(-lit / config.spot_threshold)
    inside = (px >= 0) & (px < w) & (py >= 0) & (py < h) & (rate > 1e-3)
    lam = np.bincount((py * w + px)[inside], weights=rate[inside], minlength=w * h)
    lam += config.background_rate
    lam = event_traps(lam, (h, w), traps, rng)
    counts = rng.poisson(lam)
    n_hot = config.hot_pixels * (5 if "hot_pixels" in traps else 1)
    hot = rng.choice(w * h, size=min(n_hot, w * h), replace=False)
    counts[hot] += rng.integers(200, 5000, hot.size)
    dead = rng.choice(w * h, size=min(config.dead_pixels, w * h), replace=False)
    counts[dead] = 0
    return np.clip(counts, 0, 255).astype(np.uint8).reshape(h, w)


# --- writing ---------------------------------------------------------------------------------------


def scene_stem(index: int) -> str:
    return f"scene_{index:03d}"


def write_dataset(
    out_dir: str | Path,
    config: SynthConfig = SynthConfig(),
    on_scene: Callable[[int, int], None] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write ``config.n_scenes`` scenes, the rig files and the truth into ``out_dir``.

    Refuses (:class:`InputError`) a non-empty folder unless ``overwrite``; then earlier
    ``scene_*`` files are removed first so no stale scene survives. ``on_scene(done, total)`` is
    called after each scene.
    """
    import cv2

    out = Path(out_dir)
    clear_out_dir(out, overwrite)
    map_dir = "image" if config.map_kind == "image" else "event"
    for sub in (map_dir, "lidar", "config"):
        (out / sub).mkdir(parents=True, exist_ok=True)

    camera, truth, seed = make_rig(config)
    write_rig_files(out, camera, seed, truth, config)
    for i in range(config.n_scenes):
        points, intensity, event_map = make_scene(config, i, truth, camera)
        stem = scene_stem(i)
        ok, png = cv2.imencode(".png", event_map)
        if not ok:
            raise InputError(out / map_dir / f"{stem}.png", "could not encode the PNG")
        atomic_write_bytes(out / map_dir / f"{stem}.png", png.tobytes())
        write_points_txt(out / "lidar" / f"{stem}.txt", points, intensity)
        if on_scene:
            on_scene(i + 1, config.n_scenes)
    return out


def check_out_dir(out: Path, overwrite: bool = False) -> bool:
    """Whether ``out`` already holds files; raises :class:`InputError` when it cannot be used."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(out, "exists and is not a folder")
    busy = out.is_dir() and any(out.iterdir())
    if busy and not overwrite:
        raise InputError(out, "folder is not empty (pass --force to overwrite)")
    return busy


def clear_out_dir(out: Path, overwrite: bool = False) -> None:
    """Make ``out`` ready for a new data set: refused when it is not empty unless ``overwrite``;
    then the old ``scene_*`` files and the scan cache go first."""
    if check_out_dir(out, overwrite):
        for sub in ("event", "image", "lidar"):
            for old in (out / sub).glob("scene_*"):
                old.unlink()
        shutil.rmtree(out / ".l2e_cache", ignore_errors=True)


def write_points_txt(path: Path, points: np.ndarray, intensity: np.ndarray) -> None:
    """``x,y,z,intensity`` lines (4 decimals, integer intensity), formatted in one go."""
    n = points.shape[0]
    table = np.empty((n, 4))
    table[:, :3] = points
    table[:, 3] = np.round(intensity)
    text = ("%.4f,%.4f,%.4f,%d\n" * n) % tuple(table.ravel().tolist())
    atomic_write_bytes(path, text.encode())


def write_rig_files(out: Path, camera: CameraModel, seed: Extrinsic, truth: Extrinsic, config: SynthConfig) -> None:
    """``config/config.json`` (reference format), ``camera.yaml`` (ours) and ``truth.yaml``."""
    K = camera.K.tolist()
    D = [float(x) for x in camera.D[:5]]
    cfg = {
        "cam": {
            "K": K,
            "D": D,
            "x": float(seed.translation[0]),
            "y": float(seed.translation[1]),
            "z": float(seed.translation[2]),
            "Rodrigues": seed.rotvec.tolist(),
            **dict(zip(("rx", "ry", "rz"), (float(a) for a in seed.rpy(degrees=True)))),
        }
    }
    atomic_write_bytes(out / "config" / "config.json", (json.dumps(cfg, indent=2) + "\n").encode())
    cam_yaml = {
        "camera": {"model": camera.model, "width": camera.width, "height": camera.height, "K": K, "D": D},
        "seed": {"translation": seed.translation.tolist(), "rotvec": seed.rotvec.tolist()},
    }
    header = "# Synthetic rig written by `l2e-studio synth`; seed = truth perturbed (see truth.yaml).\n"
    atomic_write_bytes(out / "camera.yaml", (header + yaml.safe_dump(cam_yaml, sort_keys=False, default_flow_style=None)).encode())
    err_deg, err_m = seed.error_to(truth)
    truth_yaml = {
        "T_cam_lidar": truth.matrix.tolist(),
        "translation": truth.translation.tolist(),
        "rotvec": truth.rotvec.tolist(),
        "rpy_deg": truth.rpy(degrees=True).tolist(),
        "seed_error": {"rotation_deg": err_deg, "translation_m": err_m},
        "generator": asdict(config),
    }
    header = "# Ground truth T_cam_lidar (X_cam = R X_lidar + t) of this synthetic dataset.\n"
    atomic_write_bytes(out / "truth.yaml", (header + yaml.safe_dump(truth_yaml, sort_keys=False, default_flow_style=None)).encode())


def read_truth(path: str | Path) -> Extrinsic:
    """The true extrinsic from a ``truth.yaml`` written by :func:`write_dataset`."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
        return Extrinsic.from_matrix(np.asarray(data["T_cam_lidar"], dtype=np.float64))
    except FileNotFoundError:
        raise InputError(path, "no truth file") from None
    except (yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
        raise InputError(path, f"expected a YAML mapping with a 4x4 T_cam_lidar ({exc})") from None


def config_with(config: SynthConfig, **changes) -> SynthConfig:
    """A copy of ``config`` with ``changes`` (None values are ignored)."""
    return replace(config, **{k: v for k, v in changes.items() if v is not None})
