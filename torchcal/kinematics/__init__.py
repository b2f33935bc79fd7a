"""MD-H kinematics kernels (strict: tensors in, tensors out; `torchcal.robots.Robot` checks input)
and `Chain`, the kinematic structure they take."""

from torchcal.kinematics.chain import Chain
from torchcal.kinematics.mdh import (DEFAULT_CHUNK, PARAM_NAMES, PARAM_UNITS, chain_jacobians, fk_frames, fk_pose,
                                     fk_positions, joint_jacobian, link_transforms, param_jacobian, positions)

__all__ = ["Chain", "DEFAULT_CHUNK", "PARAM_NAMES", "PARAM_UNITS", "chain_jacobians", "fk_frames", "fk_pose",
           "fk_positions", "joint_jacobian", "link_transforms", "param_jacobian", "positions"]
