"""MD-H kinematics kernels (strict: tensors in, tensors out; `torchcal.robots.Robot` checks input)."""

from torchcal.kinematics.mdh import (DEFAULT_CHUNK, PARAM_NAMES, PARAM_UNITS, fk_frames, fk_pose, fk_positions,
                                     joint_jacobian, link_transforms, param_jacobian)

__all__ = ["DEFAULT_CHUNK", "PARAM_NAMES", "PARAM_UNITS", "fk_frames", "fk_pose", "fk_positions", "joint_jacobian",
           "link_transforms", "param_jacobian"]
