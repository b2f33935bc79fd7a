"""Plausibility checks before and after a fit: measurement units and deviation sizes.

Units (before any fit, `check_units`). Measurements are compared with the nominal model at
the same joint angles by a registration-invariant spread: the RMS distance of the points
to their centroid, ``s = sqrt(mean |p - mean(p)|^2)`` (a rigid change of frame leaves it
unchanged, so the instrument's frame does not matter). For a right file and the right
robot the ratio ``s_measured / s_nominal`` is 1 within a few percent (a different tool
point moves it by tens of percent at most); a unit mistake moves it by about 1000.

- ratio < 1/20 with ``length_unit='mm'``: positions look like metres read as mm
  (fix: ``--length-unit m``); ratio > 20 with ``length_unit='m'``: mm read as metres
  (fix: ``--length-unit mm``). Any other ratio outside [1/20, 20] is refused too, naming
  the spreads (wrong unit or wrong robot).
- ``angle_unit='deg'`` and every joint angle within +-2 pi (6.283 "degrees") while the
  measured points spread more than 2x the nominal ones: joint angles look like radians
  read as degrees (fix: ``--angle-unit rad``). A real data set in degrees that only
  moves a few degrees keeps ratio ~1 and passes.
- ``angle_unit='rad'`` and a joint angle beyond max(2 pi, the robot's widest limit) rad
  (+ 0.01): degrees read as radians (fix: ``--angle-unit deg``).

The check needs at least 3 rows and a nominal spread of at least 1 mm; otherwise it
says nothing.

Deviation sizes (after registration and the fit, `implausible_deviations`). A calibrated
industrial arm differs from its nominal MD-H table by tenths of a mm and hundredths of a
degree; manufacturing tolerances of the links are below a few mm and assembly angles
below a few tenths of a degree. A fitted |dd|, |da| above `MAX_LENGTH_MM` = 5 mm or
|dtheta|, |dalpha|, |dbeta| above `MAX_ANGLE_DEG` = 1 deg therefore means the parameter
absorbed something else (a frame, a tool, noise along a nearly dependent direction).
The fit holds such parameters at nominal and fits again, and names them in its output
and in MODEL.json ("plausibility").
"""

from __future__ import annotations

import math

import torch

from torchcal.errors import InputError

RATIO_LIMIT = 20.0
RAD_RATIO = 2.0
MAX_LENGTH_MM = 5.0
MAX_ANGLE_DEG = 1.0


def spread_mm(p: torch.Tensor) -> float:
    """RMS distance of points p (N, 3) mm to their centroid (invariant to a rigid motion)."""
    return float((p - p.mean(0)).pow(2).sum(-1).mean().sqrt())


def check_units(m, robot, length_unit: str = "mm", angle_unit: str = "deg", where: str = "") -> dict:
    """Refuse the classic unit mistakes (module docstring) with one InputError line.

    m: Measurements (already converted with the given units); robot: the nominal robot.
    Returns {"measured_spread_mm", "nominal_spread_mm", "ratio"} (None values when the
    check could not judge).
    """
    pre = f"{where}: " if where else ""
    rev = ~robot.prismatic.cpu()  # a prismatic joint's q is a length (mm), never an angle
    q = m.q.detach().to("cpu", torch.float64)[..., rev]
    qmax_file = float(q.abs().max()) if q.numel() else 0.0  # rad inside
    if angle_unit == "rad" and q.numel():
        lim = float(robot.limits.detach().cpu()[rev].abs().max())
        bound = max(2 * math.pi, lim) + 0.01
        if qmax_file > bound:
            raise InputError(f"{pre}joint angles reach {qmax_file:.4g} rad, beyond what a joint can "
                             f"turn ({bound:.3g} rad): they look like degrees read as radians; "
                             "drop --angle-unit rad (the default is deg)")
    out = {"measured_spread_mm": None, "nominal_spread_mm": None, "ratio": None}
    if len(m) < 3:
        return out
    nominal = robot.fk(m.q.to(robot.device, robot.dtype)).detach().to("cpu", torch.float64)
    s_nom = spread_mm(nominal)
    s_meas = spread_mm(m.xyz.detach().to("cpu", torch.float64))
    if s_nom < 1.0:
        return out
    ratio = s_meas / s_nom
    out.update(measured_spread_mm=s_meas, nominal_spread_mm=s_nom, ratio=ratio)
    spreads = (f"the measured points spread {s_meas:.4g} mm (RMS distance to their centroid), "
               f"the nominal {robot.name} at these joint angles {s_nom:.4g} mm")
    if angle_unit == "deg" and q.numel() and math.degrees(qmax_file) <= 2 * math.pi + 1e-9 and ratio > RAD_RATIO:
        raise InputError(f"{pre}every joint angle lies within +-{math.degrees(qmax_file):.4g} deg and "
                         f"{spreads}: the joint angles look like radians read as degrees; "
                         "pass --angle-unit rad")
    if ratio < 1 / RATIO_LIMIT:
        if length_unit == "mm":
            raise InputError(f"{pre}{spreads} ({1 / ratio:.4g} times less): the positions look like "
                             "metres read as mm; pass --length-unit m")
        raise InputError(f"{pre}{spreads} ({1 / ratio:.4g} times less): wrong unit or wrong robot?")
    if ratio > RATIO_LIMIT:
        if length_unit == "m":
            raise InputError(f"{pre}{spreads} ({ratio:.4g} times more): the positions look like "
                             "mm read as metres; drop --length-unit m (the default is mm)")
        raise InputError(f"{pre}{spreads} ({ratio:.4g} times more): wrong unit or wrong robot?")
    return out


def implausible_deviations(model, theta: torch.Tensor, free: torch.Tensor,
                           max_length_mm: float = MAX_LENGTH_MM,
                           max_angle_deg: float = MAX_ANGLE_DEG) -> list[int]:
    """Indices of free parameters beyond the plausible size.

    theta (P,), free (P,) bool. The 5n MD-H deviations are judged against max_length_mm /
    max_angle_deg; an effect's parameters against its own `Effect.plausible_max()` (none
    for most effects: base frame and tool offsets are not deviations of the robot).
    """
    n5 = 5 * model.robot.n
    lim = torch.full((theta.shape[0],), math.inf, dtype=torch.float64)
    lim[:n5] = torch.tensor([math.radians(max_angle_deg), max_length_mm, max_length_mm,
                             math.radians(max_angle_deg), math.radians(max_angle_deg)],
                            dtype=torch.float64).repeat(model.robot.n)
    for e, sl in zip(model.effects, model.slices[1:]):
        limits = e.plausible_max()
        if limits is not None:
            lim[sl] = torch.as_tensor(limits, dtype=torch.float64)
    bad = (theta.detach().cpu().to(torch.float64).abs() > lim) & free.cpu()
    return bad.nonzero().flatten().tolist()
