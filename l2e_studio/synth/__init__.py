"""Synthetic calibration scenes with a known answer: the world (:mod:`.world`, :mod:`.layout`),
the sensors and the dataset writer (:mod:`.dataset`), and real data's failure modes on demand
(:mod:`.realism`); checkerboard sequences (:mod:`.board` the board and its rendering,
:mod:`.board_world` the room, the poses and the 16-beam lidar, :mod:`.board_views` the camera kinds,
:mod:`.board_dataset` the writer)."""

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
from .board import Board
from .board_dataset import TargetConfig, make_target_rig, make_target_scene, read_board_poses, target_config_with, write_target_dataset
from .realism import TRAPS

__all__ = [
    "Board", "SAMPLE_CONFIG", "SynthConfig", "TRAPS", "TargetConfig", "make_target_rig", "make_target_scene",
    "read_board_poses", "target_config_with", "write_target_dataset", "check_out_dir", "config_with", "lidar_directions", "make_rig",
    "make_scene", "perturb", "read_truth", "scene_stem", "write_dataset", "write_points_txt", "write_rig_files",
]
