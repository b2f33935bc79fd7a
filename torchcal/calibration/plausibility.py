"""Plausibility: the plausible size of each parameter (the unit check of measurements
before a fit is `torchcal.calibration.checks.units.check_units`).

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

#: posterior sd below this share of the plausible scale: determined by the data (module doc)
DETERMINED_RATIO = 0.5


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


class PlausibilityWarning(UserWarning):
    """Parameters beyond their plausible size where they leave torchcal (`export`)."""


def beyond_words(model, theta: torch.Tensor, limits: dict | None = None, most: int = 6) -> str | None:
    """The parameters of `model` whose |theta| (P,) exceeds its plausible size (`plausible_scales`
    with the limits a fit recorded, `FitResult.plausible_limits`, default the defaults), each
    as 'dtheta2 +20 deg (plausible 1 deg)' in the file's units (angles in degrees); None when
    there are none. The first `most` named, then how many more."""
    lim = limits or {}
    scales = plausible_scales(model, lim.get("max_length_mm", MAX_LENGTH_MM), lim.get("max_angle_deg", MAX_ANGLE_DEG))
    th = theta.detach().cpu().to(torch.float64)
    bad = (th.abs() > scales).nonzero().flatten().tolist()
    if not bad:
        return None
    names, units = model.param_names(), model.param_units()
    words = []
    for i in bad[:most]:
        unit, v, sc = units[i], float(th[i]), float(scales[i])
        if unit == "rad" or unit.startswith("rad/"):
            unit, v, sc = "deg" + unit[3:], math.degrees(v), math.degrees(sc)
        words.append(f"{names[i]} {v:+.4g} {unit} (plausible {sc:.3g} {unit})")
    more = f" and {len(bad) - most} more" if len(bad) > most else ""
    return ", ".join(words) + more


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


def undetermined(value: float, sd: float, scale: float, ratio: float = DETERMINED_RATIO) -> str | None:
    """Why one parameter is not determined by the data (module doc): 'prior' when its
    posterior sd is at least `ratio` times its plausible scale, else 'beyond' when
    |value| exceeds the scale, else None (determined). value, sd, scale in its unit."""
    if sd >= ratio * scale:
        return "prior"
    return "beyond" if abs(value) > scale else None


def determination(fit, new: list, ctx, ratio: float = DETERMINED_RATIO, partners: bool = True) -> list[dict]:
    """Why the parameters `new` (names) of a fitted model (`FitResult`) are not determined
    by its data: one dict per offending parameter, {"name", "value", "sd", "scale" (its
    unit, `unit`), "why": 'prior' (posterior sd >= ratio x scale, module doc) or 'beyond'
    (|value| > scale), "partner", "r2" (`collinear_with` on the position Jacobian at the
    solution, context ctx)}. Parameters held at nominal (not identifiable) or without a plausible scale
    are not judged. Empty: every one judged is determined and within its plausible size.
    partners=False: "partner" '' and "r2" 0.0 (no Jacobian, no regression), for a caller
    that reads which parameters and why only."""
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
        why = undetermined(v, sd, s, ratio)
        if why is None:
            continue
        if not partners:
            partner, r2 = "", 0.0
        else:
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


#: a prior costs fit quality visibly when the fit's rms exceeds the rms of the same fit
#: under the default plausible scales by more than this factor (a weak prior, as meant,
#: moves the rms by far less: parameters the data determine are left as they are)
PRIOR_COST_RATIO = 1.1


def prior_cost(fit, reference) -> dict:
    """What tighter plausible scales cost a fit (`FitResult`) against `reference`, the same
    fit under the default scales (MAX_LENGTH_MM, MAX_ANGLE_DEG): {"rms_mm", "reference_rms_mm",
    "beyond": {"length" | "angle" | "effects": [names]} the parameters free in both whose
    reference value lies beyond `fit`'s own scale (dd, da; dtheta, dalpha, dbeta; the
    effects'), "costly": rms_mm > PRIOR_COST_RATIO * reference_rms_mm and some parameter beyond}."""
    lim = fit.plausible_limits or {}
    model = fit.model
    scales = plausible_scales(model, lim.get("max_length_mm"), lim.get("max_angle_deg"))
    free = fit.report.free.detach().cpu().bool() & reference.report.free.detach().cpu().bool()
    theta = reference.theta.detach().cpu().to(torch.float64)
    names, units, n5 = model.param_names(), model.param_units(), 5 * model.robot.n
    beyond: dict = {}
    for i in (free & torch.isfinite(scales) & (theta.abs() > scales)).nonzero().flatten().tolist():
        group = "effects" if i >= n5 else "length" if units[i] == "mm" else "angle"
        beyond.setdefault(group, []).append(names[i])
    rms, ref = float(fit.rms_mm), float(reference.rms_mm)
    return {"rms_mm": rms, "reference_rms_mm": ref, "beyond": beyond,
            "costly": bool(beyond) and rms > PRIOR_COST_RATIO * ref}
