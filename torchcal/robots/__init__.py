"""Robots: the nominal `Robot` and its presets, random poses and workspace sampling.

Robot files and URDF import/export are file formats (`torchcal.io.robot_file`,
`torchcal.io.urdf`); `torchcal.robot(name)` (a preset, a `Robot` or a robot file) is
`torchcal.io.robot_file.robot`."""

from torchcal.robots.poses import random_poses
from torchcal.robots.robot import PRESETS, Robot, preset
from torchcal.robots.workspace import Workspace, sample_workspace

__all__ = ["random_poses", "PRESETS", "Robot", "preset", "Workspace", "sample_workspace"]
