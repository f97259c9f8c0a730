"""Spinning multi-beam lidars the synthetic worlds can be seen by: ring elevations and azimuth
step after the data sheets, and the rays of one revolution. Lidar frame: x forward, y left, z up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RING_ELEVATIONS_DEG = np.arange(-15.0, 15.1, 2.0)  # VLP-16


@dataclass(frozen=True)
class LidarModel:
    """A spinning multi-beam lidar: ring elevations, azimuth step, range noise and dropouts."""

    elevations_deg: tuple[float, ...] = tuple(RING_ELEVATIONS_DEG)
    azimuth_step_deg: float = 0.2
    range_noise_m: float = 0.015
    dropout: float = 0.01
    max_range_m: float = 100.0


#: ring elevations (deg) and azimuth step (deg) of Velodyne VLP-16, HDL-32E, HDL-64E and Ouster
#: OS1-128 (an HDL-64E looks mostly down: +2 to -24.9 deg, so a board held high is cut by its top beam)
LIDARS = {
    "vlp16": dict(elevations_deg=tuple(RING_ELEVATIONS_DEG), azimuth_step_deg=0.2),
    "hdl32": dict(elevations_deg=tuple(np.linspace(-30.67, 10.67, 32)), azimuth_step_deg=0.16),
    "hdl64": dict(elevations_deg=tuple(np.linspace(-24.9, 2.0, 64)), azimuth_step_deg=0.17),
    "os128": dict(elevations_deg=tuple(np.linspace(-22.5, 22.5, 128)), azimuth_step_deg=0.35),
}


def ring_directions(elevations_deg, azimuth_step_deg: float, rng: np.random.Generator,
                    hfov_deg: float = 360.0) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays (N, 3) of one revolution within ``hfov_deg`` centred on x (the firing phase
    random), ring by ring, and each ray's ring index (N,) uint16."""
    el = np.radians(np.asarray(elevations_deg, dtype=float))
    step = np.radians(azimuth_step_deg)
    if hfov_deg >= 360.0:
        az = rng.uniform(0, step) + np.arange(int(round(2 * np.pi / step))) * step
    else:
        half = np.radians(hfov_deg) / 2
        az = np.arange(-half + rng.uniform(0, step), half, step)
    E, A = np.meshgrid(el, az, indexing="ij")
    ring = np.repeat(np.arange(el.size, dtype=np.uint16), az.size)
    dirs = np.column_stack([(np.cos(E) * np.cos(A)).ravel(), (np.cos(E) * np.sin(A)).ravel(), np.sin(E).ravel()])
    return dirs, ring
