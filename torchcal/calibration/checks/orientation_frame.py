"""Orientations measured in another frame than the positions: `check_orientation_frame`.

One measuring frame carries both x, y, z and rx, ry, rz in the model (the base_frame
effect rotates both). A file whose orientations were left in the instrument's frame while
its positions were moved into another (an alignment in the tracker's software, the robot
base frame) cannot be described by any model; the fit then bends the geometry to split the
difference (UR10 series D, orientations turned 20 deg about z: position rms 1.29 mm instead
of 0.40 mm, dalpha5 +13.9 deg) with exit 0. The orientation check of
`torchcal.calibration.checks.orientation.orientation_mismatch` lets the orientations choose a frame of
their own (a large unknown tool offset tilts a frame taken from the positions alone), so
it passes such a file; this check takes the positions' frame with the tool offset fitted,
which the offset does not tilt.
"""

from __future__ import annotations

import math

import torch

from torchcal.calibration.checks.orientation import own_frame, tool_rotation_rms_deg
from torchcal.errors import InputError

ORIENT_DEG = 5.0  # rms angle (deg) beyond which orientations are not the tool's in the positions' frame
ROUNDS = 50  # alternations of the frame and tool-offset fit


def position_frame(pose: torch.Tensor, xyz: torch.Tensor, rounds: int = ROUNDS):
    """The measuring frame (F (3, 3), f (3,)) and tool offset u (3,) mm (in the TCP frame)
    that best place the nominal TCP frames `pose` (N, 4, 4) onto the measured positions
    `xyz` (N, 3) mm: x_i = F (o_i + A_i u) + f, by alternating the closed-form frame
    (Kabsch) and the linear least-squares offset."""
    from torchcal.rotations import kabsch

    A, o = pose[:, :3, :3], pose[:, :3, 3]
    u = torch.zeros(3, dtype=xyz.dtype)
    for _ in range(rounds):
        F, f = kabsch(o + A @ u, xyz)
        rhs = (xyz - f) @ F - o  # (N, 3): F^T (x - f) - o
        u = torch.linalg.lstsq(A.reshape(-1, 3), rhs.reshape(-1, 1)).solution.flatten()
    return F, f, u


def check_orientation_frame(model, m) -> None:
    """InputError (one line) when the orientations of `m` (rx, ry, rz) disagree with the
    nominal tool orientations of `model`'s robot by more than ORIENT_DEG rms in the
    measuring frame of its positions (`position_frame`): they are in another frame. Data
    without rx, ry, rz or with fewer than 6 rows are not judged. Call it after
    `torchcal.calibration.checks.robot_data.check_robot_data_of`, which refuses orientations that
    fit in no frame (another convention or unit)."""
    if m.rxyz is None or len(m) < 6:
        return
    rob = model.robot
    with torch.no_grad():
        pose = rob.fk_pose(m.q.to(rob.device, rob.dtype)).detach().to("cpu", torch.float64)
    xyz = m.xyz.detach().to("cpu", torch.float64)
    measured = m.rotation.detach().to("cpu", torch.float64)
    F, _, _ = position_frame(pose, xyz)
    rms = tool_rotation_rms_deg(pose[:, :3, :3], measured, F)
    if rms <= ORIENT_DEG:
        return
    own = own_frame(pose[:, :3, :3], measured, F)  # the orientations' own frame
    turn = math.degrees(math.acos(max(-1.0, min(1.0, (float(torch.trace(own @ F.T)) - 1) / 2))))
    raise InputError(f"{m.source or 'data'}: rx, ry, rz disagree with the tool orientation of {rob.name} by rms "
                     f"{rms:.4g} deg in the measuring frame of x, y, z, but fit in a frame of their own turned "
                     f"{turn:.4g} deg from it (to rms {tool_rotation_rms_deg(pose[:, :3, :3], measured, own):.3g} "
                     "deg): the orientations are in another frame than the positions (one moved by an alignment, "
                     "the other not?); give both in one frame, or drop the three columns")
