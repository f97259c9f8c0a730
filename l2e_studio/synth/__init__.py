"""Synthetic calibration scenes with a known answer: the world (:mod:`.world`, :mod:`.layout`),
the sensors and the dataset writer (:mod:`.dataset`), and real data's failure modes on demand
(:mod:`.realism`)."""

from .dataset import (
    SAMPLE_CONFIG,
    SynthConfig,
    check_out_dir,
    config_with,
    lidar_directions,
    make_rig,
    make_scene,
    perturb,
    read_truth,
    scene_stem,
    write_dataset,
    write_points_txt,
    write_rig_files,
)
from .realism import TRAPS

__all__ = [
    "SAMPLE_CONFIG", "SynthConfig", "TRAPS", "check_out_dir", "config_with", "lidar_directions", "make_rig",
    "make_scene", "perturb", "read_truth", "scene_stem", "write_dataset", "write_points_txt", "write_rig_files",
]
