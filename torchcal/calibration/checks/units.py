"""Measurements in another unit (before any fit, `check_units`).

Measurements are compared with the nominal model at the same joint angles by a
registration-invariant spread: the RMS distance of the points to their centroid,
``s = sqrt(mean |p - mean(p)|^2)`` (`spread_mm`; a rigid change of frame leaves it
unchanged, so the instrument's frame does not matter). For a right file and the right
robot the ratio ``s_measured / s_nominal`` is 1 within a few percent (a different tool
point moves it by tens of percent at most); a unit mistake moves it by about 1000.

- ratio < 1/20 with ``length_unit='mm'``: positions look like metres read as mm
  (fix: ``length_unit='m'``), or inches read as mm when the ratio is 1/25.4 within 10 %
  (no unit option: convert the file); ratio > 20 with ``length_unit='m'``: mm read as metres
  (fix: ``length_unit='mm'``). Any other ratio outside [1/20, 20] is refused too, naming
  the spreads (wrong unit or wrong robot).
- ``angle_unit='deg'`` and every joint angle within +-2 pi (6.283 "degrees") while the
  measured points spread more than 2x the nominal ones: joint angles look like radians
  read as degrees (fix: ``angle_unit='rad'``). A real data set in degrees that only
  moves a few degrees keeps ratio ~1 and passes.
- ``angle_unit='rad'`` and a joint angle beyond max(2 pi, the robot's widest limit) rad
  (+ 0.01): degrees read as radians (fix: ``angle_unit='deg'``, `beyond_turn`).

The check needs at least 3 rows and a nominal spread of at least 1 mm; otherwise it
says nothing. The units that numbers read as mm are mistaken in (`MISREAD`, `misread_length`)
are those the target check names too (`torchcal.calibration.checks.targets`), and a spread
ratio near a unit's factor is named in a gross mismatch's line (`units_hint`).
"""

from __future__ import annotations

import math

import torch

from torchcal.errors import InputError

RATIO_LIMIT = 20.0
RAD_RATIO = 2.0
INCH_MM = 25.4


#: the length units that numbers read as mm are mistaken in: factor to mm, the words naming
#: the mistake, the `InputError.fix` (None: no unit option reads them; convert the file)
MISREAD = {"metres": (1000.0, "metres read as mm", ("length_unit", "m")),
           "inches": (INCH_MM, f"inches read as mm; convert them to mm (x {INCH_MM:g})", None)}


def misread_length(ratio: float) -> str | None:
    """The unit (a `MISREAD` key) of numbers read as mm that are `ratio` times the size
    they should have: 'inches' when 1/25.4 within 10 %, 'metres' at any other ratio below
    1 / RATIO_LIMIT, else None."""
    if abs(math.log(ratio * INCH_MM)) < math.log(1.1):
        return "inches"
    return "metres" if ratio < 1 / RATIO_LIMIT else None


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
    if angle_unit == "rad":
        bound = beyond_turn(m.q, robot)
        if bound is not None:
            raise InputError(f"{pre}joint angles reach {qmax_file:.4g} rad, beyond what a joint can "
                             f"turn ({bound:.3g} rad): they look like degrees read as radians",
                             fix=("angle_unit", "deg"))
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
                         f"{spreads}: the joint angles look like radians read as degrees",
                         fix=("angle_unit", "rad"))
    if ratio < 1 / RATIO_LIMIT:
        if length_unit == "mm":
            _, words, fix = MISREAD[misread_length(ratio)]
            raise InputError(f"{pre}{spreads} ({1 / ratio:.4g} times less): the positions look like {words}",
                             fix=fix)
        raise InputError(f"{pre}{spreads} ({1 / ratio:.4g} times less): wrong unit or wrong robot?")
    if ratio > RATIO_LIMIT:
        if length_unit == "m":
            raise InputError(f"{pre}{spreads} ({ratio:.4g} times more): the positions look like "
                             "mm read as metres", fix=("length_unit", "mm"))
        raise InputError(f"{pre}{spreads} ({ratio:.4g} times more): wrong unit or wrong robot?")
    return out


def beyond_turn(q: torch.Tensor, robot) -> float | None:
    """The bound max(2 pi, the robot's widest revolute limit) + 0.01 rad when a revolute
    joint value of q (..., n) rad / mm lies beyond it (degrees taken for radians), else None."""
    rev = ~robot.prismatic.cpu()
    a = q.detach().to("cpu", torch.float64)[..., rev]
    if not a.numel():
        return None
    bound = max(2 * math.pi, float(robot.limits.detach().cpu()[rev].abs().max())) + 0.01
    return bound if float(a.abs().max()) > bound else None


def units_hint(ratio: float) -> str:
    # ratio = measured / modelled spread: numbers 1000 times too small are metres read as mm
    for f, what in ((1e-3, "metres read as mm (length unit m)"), (1000.0, "mm read as metres (length unit mm)"),
                    (1 / INCH_MM, "inches read as mm"),
                    (math.degrees(1.0), "radians read as degrees (angle unit rad)")):
        if abs(math.log(ratio / f)) < math.log(1.5):
            return f"; the spread ratio {ratio:.4g} points at {what}"
    return ""
