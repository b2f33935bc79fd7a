"""Measured orientations (rx, ry, rz) that cannot be the robot's tool frames
(`orientation_mismatch`): another angle convention or unit, named when one of the usual
readings fits (`orientation_readings`). An orientation uncertainty (sigma_deg) given for
data without rx, ry, rz weighs nothing: one warning says so (`warn_unused_sigma_deg`).
"""

from __future__ import annotations

import math
import warnings

import torch

from torchcal.calibration.checks.verdict import rms_of

ORIENT_DEG = 5.0  # rms angle (deg) between measured and nominal tool orientations beyond which they are not the robot's


def own_frame(nominal: torch.Tensor, measured: torch.Tensor, frame: torch.Tensor, rounds: int = 10) -> torch.Tensor:
    """The measuring-frame rotation F (3, 3) that best turns the nominal rotations A (N, 3, 3)
    onto the measured ones Rm (N, 3, 3) as F A X, starting from `frame` (3, 3) and refined in
    turn with the constant tool rotation X (Procrustes each, `rounds` times)."""
    from torchcal.rotations import nearest_rotation, procrustes_rotation

    F = frame
    for _ in range(rounds):
        x = procrustes_rotation(F @ nominal, measured)
        F = nearest_rotation((measured @ (nominal @ x).transpose(-1, -2)).sum(0))
    return F


def tool_rotation_rms_deg(nominal: torch.Tensor, measured: torch.Tensor, F: torch.Tensor) -> float:
    """RMS angle (deg) between measured rotations (N, 3, 3) and F A_i X, A_i the nominal ones
    (N, 3, 3), with the constant tool rotation X fitted (Procrustes) and F (3, 3) fixed."""
    from torchcal.rotations import procrustes_rotation, so3_error

    a = F @ nominal
    x = procrustes_rotation(a, measured)
    return math.degrees(rms_of(so3_error(a @ x, measured).norm(dim=-1)))


def _orientation_rms_deg(nominal: torch.Tensor, measured: torch.Tensor, frame: torch.Tensor,
                         rounds: int = 10) -> float:
    """RMS angle (deg) between measured rotations Rm (N, 3, 3) and the nominal ones A
    (N, 3, 3) as F A X, with the measuring-frame rotation F (from `frame` (3, 3), the
    positions' Kabsch) and the constant tool rotation X refined in turn (`own_frame`): a
    large unknown tool offset, which tilts the positions' F, does not count."""
    return tool_rotation_rms_deg(nominal, measured, own_frame(nominal, measured, frame, rounds))


def orientation_readings(rxyz: torch.Tensor):
    """Yield (phrase, (N, 3, 3) rotations) for other readings of rx, ry, rz (N, 3) as read
    (fixed-axis XYZ in degrees, held in rad): radians read as degrees, intrinsic
    (moving-axis) XYZ angles, a rotation vector (axis-angle, as UR controllers report the
    TCP pose), each in degrees or in radians read as degrees."""
    from torchcal.rotations import fixed_xyz_to_matrix, rotvec_to_matrix

    def intrinsic(r):  # R = Rx(rx) Ry(ry) Rz(rz), each factor a fixed-axis rotation about one axis
        zero = torch.zeros_like(r[:, 0])
        return (fixed_xyz_to_matrix(torch.stack([r[:, 0], zero, zero], -1))
                @ fixed_xyz_to_matrix(torch.stack([zero, r[:, 1], zero], -1))
                @ fixed_xyz_to_matrix(torch.stack([zero, zero, r[:, 2]], -1)))

    for scale, unit in ((1.0, ""), (180.0 / math.pi, " in radians (read as degrees)")):
        r = rxyz * scale
        if scale != 1.0:
            yield f"fixed-axis XYZ angles{unit}", fixed_xyz_to_matrix(r)
        yield f"intrinsic (moving-axis) XYZ angles{unit}", intrinsic(r)
        yield f"a rotation vector (axis-angle, as UR controllers report){unit}", \
            torch.stack([rotvec_to_matrix(v) for v in r])


def orientation_mismatch(model, m) -> str | None:
    """One line when the measured orientations of `m` (rx, ry, rz) cannot be the tool frames
    of `model`'s nominal robot: the RMS angle between them, after the measuring frame's
    rotation (Kabsch on the positions, which agree: `check_robot_data`) and the best
    constant tool rotation (the fit's Procrustes step), beyond ORIENT_DEG = 5 deg (an
    uncalibrated arm is within a degree or so). The line names the reading that fits
    (`orientation_readings`), if one does. None for data without rx, ry, rz, fewer than 3
    rows, or when they agree."""
    from torchcal.rotations import kabsch

    if m.rxyz is None or len(m) < 3:
        return None
    rob = model.robot
    with torch.no_grad():
        q = m.q.to(rob.device, rob.dtype)
        pose = rob.fk_pose(q).detach().to("cpu", torch.float64)  # (N, 4, 4) the nominal tool frames
    nominal, p = pose[:, :3, :3], pose[:, :3, 3]
    frame, _ = kabsch(p, m.xyz.detach().to("cpu", torch.float64))
    measured = m.rotation.detach().to("cpu", torch.float64)
    rms = _orientation_rms_deg(nominal, measured, frame)
    if rms <= ORIENT_DEG:
        return None
    hint = next((phrase for phrase, R in orientation_readings(m.rxyz.detach().to("cpu", torch.float64))
                 if _orientation_rms_deg(nominal, R, frame) <= ORIENT_DEG), None)
    what = m.source or "data"
    cause = f"they look like {hint}" if hint is not None else "another angle convention or unit?"
    return (f"{what}: rx, ry, rz disagree with the tool orientation of {rob.name} by rms {rms:.4g} deg after the best "
            f"measuring-frame and tool rotations (an uncalibrated arm is within a degree or so): {cause}; rx, ry, rz "
            "are fixed-axis XYZ angles, R = Rz(rz) Ry(ry) Rx(rx), in the angle unit (or drop the three columns)")


class UnusedSigmaWarning(UserWarning):
    """An orientation uncertainty (sigma_deg) given for data without rx, ry, rz: it weighs
    nothing there."""


def sigma_deg_unused(sigma_deg: float | None, m) -> bool:
    """Whether the orientation uncertainty sigma_deg (deg; None: not given, the default)
    was given for measurements m without rx, ry, rz: it weighs measured orientations
    against positions, so on positions alone it changes nothing."""
    return sigma_deg is not None and m.rxyz is None


def warn_unused_sigma_deg(sigma_deg: float | None, m, stacklevel: int = 1) -> bool:
    """One `UnusedSigmaWarning` when `sigma_deg_unused`; stacklevel: as for
    `warnings.warn`, counted from the caller. Returns whether it warned."""
    if not sigma_deg_unused(sigma_deg, m):
        return False
    warnings.warn(f"{m.source or 'measurements'}: sigma_deg {sigma_deg:g} is ignored: the data have no rx, ry, rz "
                  "columns (it weighs measured orientations against positions)", UnusedSigmaWarning,
                  stacklevel=stacklevel + 1)
    return True
