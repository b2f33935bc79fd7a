"""Plausibility: measurement units before a fit, and the plausible size of each parameter.

Units (before any fit, `check_units`). Measurements are compared with the nominal model at
the same joint angles by a registration-invariant spread: the RMS distance of the points
to their centroid, ``s = sqrt(mean |p - mean(p)|^2)`` (a rigid change of frame leaves it
unchanged, so the instrument's frame does not matter). For a right file and the right
robot the ratio ``s_measured / s_nominal`` is 1 within a few percent (a different tool
point moves it by tens of percent at most); a unit mistake moves it by about 1000.

- ratio < 1/20 with ``length_unit='mm'``: positions look like metres read as mm
  (fix: ``length_unit='m'``); ratio > 20 with ``length_unit='m'``: mm read as metres
  (fix: ``length_unit='mm'``). Any other ratio outside [1/20, 20] is refused too, naming
  the spreads (wrong unit or wrong robot).
- ``angle_unit='deg'`` and every joint angle within +-2 pi (6.283 "degrees") while the
  measured points spread more than 2x the nominal ones: joint angles look like radians
  read as degrees (fix: ``angle_unit='rad'``). A real data set in degrees that only
  moves a few degrees keeps ratio ~1 and passes.
- ``angle_unit='rad'`` and a joint angle beyond max(2 pi, the robot's widest limit) rad
  (+ 0.01): degrees read as radians (fix: ``angle_unit='deg'``).

The check needs at least 3 rows and a nominal spread of at least 1 mm; otherwise it
says nothing.

Plausible sizes (the prior of the fit, `plausible_scales`). A calibrated industrial arm
differs from its nominal MD-H table by tenths of a mm and hundredths of a degree;
manufacturing tolerances of the links are below a few mm and assembly angles below a few
tenths of a degree. Each parameter i gets a physical scale s_i: `MAX_LENGTH_MM` = 5 mm for
dd, da, `MAX_ANGLE_DEG` = 1 deg for dtheta, dalpha, dbeta, and each effect's
`Effect.plausible_max()` (docs/effects.md). The fit adds one residual row
``rho * theta_i / s_i`` per parameter (a Gaussian prior theta_i ~ N(0, s_i^2) for
residuals of per-axis scale rho, rho estimated from the fit itself): a parameter that the
data determine well is untouched, one along a nearly dependent direction (a combination
that cancels on the calibration poses) is shrunk towards nominal instead of growing to
metres. Nothing is held or refitted for being large; a parameter that still ends beyond
its scale is named (`beyond_plausible`, `FitResult.implausible`) in the output and in
MODEL.json ("plausibility"), as a sign that it absorbed something else.

Determined by the data or set by the prior (`set_by_prior`, `determined`). The fit's
standard errors are posterior ones (`torchcal.calibration.covariance`): for one
parameter, posterior variance = 1 / (data information + prior information), the prior's
information being 1 / s_i^2. A posterior sd below ``DETERMINED_RATIO`` (0.5) times s_i
means the posterior variance is below a quarter of the prior's, i.e. the data carry at
least three times the prior's information about it: its value is at least three
quarters data. A free parameter whose posterior sd is at or above that is "set by the
prior": its value is the prior's shrinkage of a direction the data barely see (typically
a combination collinear with other parameters), not a measurement; the output labels it
so and never lists it as a measured deviation.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from torchcal.defaults import MAX_ANGLE_DEG, MAX_LENGTH_MM
from torchcal.errors import InputError

RATIO_LIMIT = 20.0
RAD_RATIO = 2.0
#: posterior sd below this share of the plausible scale: determined by the data (module doc)
DETERMINED_RATIO = 0.5


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
            raise InputError(f"{pre}{spreads} ({1 / ratio:.4g} times less): the positions look like "
                             "metres read as mm", fix=("length_unit", "m"))
        raise InputError(f"{pre}{spreads} ({1 / ratio:.4g} times less): wrong unit or wrong robot?")
    if ratio > RATIO_LIMIT:
        if length_unit == "m":
            raise InputError(f"{pre}{spreads} ({ratio:.4g} times more): the positions look like "
                             "mm read as metres", fix=("length_unit", "mm"))
        raise InputError(f"{pre}{spreads} ({ratio:.4g} times more): wrong unit or wrong robot?")
    return out


def plausible_scales(model, max_length_mm: float | None = MAX_LENGTH_MM,
                     max_angle_deg: float | None = MAX_ANGLE_DEG) -> torch.Tensor:
    """(P,) float64 plausible size s_i of every parameter, in its unit (inf: no prior).

    The 5n MD-H deviations: `max_length_mm` for dd, da and `max_angle_deg` (as rad) for
    dtheta, dalpha, dbeta (each None drops its own prior only); an effect's parameters: its
    `Effect.plausible_max()` (None or inf entries: none, e.g. base frame and tool offset,
    which are frames, not deviations of the robot)."""
    n5 = 5 * model.robot.n
    s = torch.full((model.n_params,), math.inf, dtype=torch.float64)
    ang = math.inf if max_angle_deg is None else math.radians(max_angle_deg)
    length = math.inf if max_length_mm is None else max_length_mm
    s[:n5] = torch.tensor([ang, length, length, ang, ang], dtype=torch.float64).repeat(model.robot.n)
    for e, sl in zip(model.effects, model.slices[1:]):
        limits = e.plausible_max()
        if limits is not None:
            s[sl] = torch.as_tensor(limits, dtype=torch.float64)
    return s


def beyond_plausible(model, theta: torch.Tensor, free: torch.Tensor, scales: torch.Tensor) -> list[str]:
    """Names of free parameters whose fitted |theta| (P,) exceeds its plausible scale."""
    bad = (theta.detach().cpu().to(torch.float64).abs() > scales) & free.cpu()
    names = model.param_names()
    return [names[i] for i in bad.nonzero().flatten().tolist()]


def set_by_prior(model, std: torch.Tensor, free: torch.Tensor, scales: torch.Tensor,
                 ratio: float = DETERMINED_RATIO) -> list[str]:
    """Names of free parameters with a plausible scale whose posterior sd (P,) (the fit's
    `std`, the prior included) is at least `ratio` times that scale (module doc)."""
    sd = std.detach().cpu().to(torch.float64)
    bad = torch.isfinite(scales) & free.cpu() & (sd >= ratio * scales)
    names = model.param_names()
    return [names[i] for i in bad.nonzero().flatten().tolist()]


def collinear_with(A: torch.Tensor, i: int, names: list, free: torch.Tensor) -> tuple[str, float]:
    """Which parameter column i of the Jacobian A (R, P) is collinear with: R^2 of column
    i regressed on the other free columns (1: exactly collinear), and the partner, the
    column whose removal lowers that R^2 most (what explains column i that nothing else
    does). Unit-norm columns, least squares. ('', 0.0) when there is no other column.

    The drop of R^2 when column j is removed is x_j^2 / [(B^T B)^+]_jj (x the minimum-norm
    least-squares coefficients on the other columns B, a unit), and 0 for a column in an
    exact dependency of B (removing it leaves the span as it is): one SVD of B with
    lstsq's rank cut instead of a regression per column; when a singular value lies near
    that cut, each drop is a regression of its own."""
    M = A.detach().cpu().to(torch.float64).numpy()
    others = [j for j in free.nonzero().flatten().tolist() if j != i]
    if not others or not np.linalg.norm(M[:, i]) > 0:
        return "", 0.0
    a = M[:, i] / np.linalg.norm(M[:, i])
    B = M[:, others] / np.linalg.norm(M[:, others], axis=0).clip(1e-300)

    def r2(cols):
        if not cols:
            return 0.0
        x = np.linalg.lstsq(B[:, cols], a, rcond=None)[0]
        return 1.0 - float(((a - B[:, cols] @ x) ** 2).sum())

    idx = list(range(len(others)))
    full = r2(idx)
    _, s, vt = np.linalg.svd(B, full_matrices=False)
    cut = np.finfo(float).eps * max(B.shape) * s[0]  # lstsq's (rcond=None)
    r = int((s > cut).sum())
    # without a column, lstsq's cut is at least eps * max(shape) * s[1] (interlacing):
    # no singular value within a factor 10 of [that, cut] means every regression keeps
    # the rank the closed form uses
    low = np.finfo(float).eps * max(B.shape) * (s[1] if len(s) > 1 else s[0])
    if not np.any((s > low / 10) & (s < cut * 10)):
        v = vt[:r].T / s[:r]  # (m, r)
        x = v @ (v.T @ (B.T @ a))
        in_dependency = (vt[r:] ** 2).sum(0) > 1e-12  # (m,)
        drop = np.where(in_dependency, 0.0, x ** 2 / (v ** 2).sum(-1).clip(1e-300))
    else:
        drop = [full - r2([k for k in idx if k != j]) for j in idx]
    return names[others[int(np.argmax(drop))]], min(max(full, 0.0), 1.0)


def determination(fit, new: list, ctx, ratio: float = DETERMINED_RATIO) -> list[dict]:
    """Why the parameters `new` (names) of a fitted model (`FitResult`) are not determined
    by its data: one dict per offending parameter, {"name", "value", "sd", "scale" (its
    unit, `unit`), "why": 'prior' (posterior sd >= ratio x scale, module doc) or 'beyond'
    (|value| > scale), "partner", "r2" (`collinear_with` on the position Jacobian at the
    solution, context ctx)}. Parameters held at nominal (not identifiable) or without a plausible scale
    are not judged. Empty: every one judged is determined and within its plausible size."""
    model = fit.model
    names, units = model.param_names(), model.param_units()
    scales = plausible_scales(model)
    out, A = [], None
    for n in new:
        i = names.index(n)
        s = float(scales[i])
        if not math.isfinite(s) or not bool(fit.report.free[i]):
            continue
        v, sd = float(fit.theta[i]), float(fit.std[i])
        why = "prior" if sd >= ratio * s else "beyond" if abs(v) > s else None
        if why is None:
            continue
        if A is None:
            A = model.jacobian(fit.theta, ctx).detach().reshape(-1, len(names))
        partner, r2 = collinear_with(A, i, names, fit.report.free)
        out.append({"name": n, "value": v, "sd": sd, "scale": s, "unit": units[i], "why": why,
                    "partner": partner, "r2": r2})
    return out


def determination_words(items: list[dict]) -> str:
    """One phrase for `determination`'s findings, in degrees and mm: 'not determined:
    gear_2_sin1 +- 0.097 deg against a plausible 0.1 deg; collinear with dtheta2 (R^2 0.9998)'."""
    def q(x, unit):
        return (f"{math.degrees(x):.3g} deg" if unit == "rad" else f"{x:.3g} {unit}" if unit != "1" else f"{x:.3g}")

    parts = []
    for d in items:
        head = (f"not determined: {d['name']} +- {q(d['sd'], d['unit'])} against a plausible {q(d['scale'], d['unit'])}"
                if d["why"] == "prior" else
                f"beyond plausible: {d['name']} {q(d['value'], d['unit'])} against a plausible {q(d['scale'], d['unit'])}")
        if d["partner"]:
            head += f"; collinear with {d['partner']} (R^2 {d['r2']:.4f} on the other parameters)"
        parts.append(head)
    return "; ".join(parts)
