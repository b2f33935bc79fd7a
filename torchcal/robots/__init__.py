"""Robots: the nominal `Robot` and its presets, robot files, URDF import/export and random poses.

`torchcal.robot(name)` (the preset / robot-file loader) lives at the top level: here the
name belongs to the module `torchcal.robots.robot`."""

from torchcal.robots.poses import random_poses
from torchcal.robots.robot import PRESETS, Robot
from torchcal.robots.workspace import Workspace, sample_workspace
from torchcal.robots.robot_file import (check_same_robot, load_robot_file, model_robot, robot_from_dict,
                                        robot_to_dict, write_robot_file)
from torchcal.robots.urdf import calibrated_urdf, minimal_urdf, read_chain, robot_from_urdf, urdf_fk

__all__ = ["random_poses", "PRESETS", "Robot", "Workspace", "sample_workspace", "check_same_robot", "load_robot_file", "model_robot",
           "robot_from_dict", "robot_to_dict", "write_robot_file", "calibrated_urdf", "minimal_urdf", "read_chain",
           "robot_from_urdf", "urdf_fk"]
