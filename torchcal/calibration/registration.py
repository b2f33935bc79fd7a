"""Registration: the rigid frame of the measuring instrument, in closed form, before a fit.

Measurements come in the instrument's (laser tracker's) frame, which may be rotated and
shifted arbitrarily against the robot's base. A fit that starts with the base frame at
identity then starts far from the solution (and trades the rotation for joint-1
deviations). `register_frame` computes the rigid motion that best maps the nominal model's
points onto the measured ones (Kabsch / Umeyama without scale: SVD of the
cross-covariance) and writes it into the model's `base_frame` parameters, so that the
fit starts at the registered frame with every deviation of the robot at zero.

`reregister` moves a fitted model to a new set-up: only the measuring frame (base frame,
and the tool offset if asked) is estimated on new measurements, from the closed-form
start, while the geometry, the effects, their covariance and the calibrated range stay
(docs/registration.md).

The fit does the same for measured orientations: the constant rotation between
the robot's nominal tool frame and the measured (e.g. T-Mac) frame, as the orthogonal
Procrustes solution over all rows (`torchcal.rotations.procrustes_rotation`).
"""

from __future__ import annotations

import math

import torch

from torchcal.rotations import kabsch, matrix_to_fixed_xyz, matrix_to_rotvec, rotvec_to_matrix


#: `torchcal register` warns when the registered rms exceeds this many times the model's
#: training rms (the model does not carry over to the new session)
FAR_FACTOR = 3.0


class TransferWarning(UserWarning):
    """A registered model's error on the new session is far above its training error."""


def far_from_training(rms_mm: float, training_rms_mm: float | None, factor: float = FAR_FACTOR) -> str | None:
    """The warning line when `rms_mm` (after registration) exceeds `factor` times the
    model's training rms (None when it does not, or the training rms is unknown)."""
    if training_rms_mm is None or not training_rms_mm > 0 or rms_mm <= factor * training_rms_mm:
        return None
    return (f"registered rms {rms_mm:.4g} mm is {rms_mm / training_rms_mm:.1f}x the model's training rms "
            f"{training_rms_mm:.4g} mm (warning above {factor:g}x): the model does not carry over to this "
            f"session: are its terms those of the session it was fitted in? (docs/registration.md)")


def frame_uncertainty(res, poses: torch.Tensor, tool: bool = False) -> torch.Tensor:
    """(K,) mm: 1-sigma of the positions a registered model `res` (of `reregister`) predicts
    at poses (K, n) rad / mm, from the registration's own uncertainty alone (the covariance
    block of the measuring frame, and the tool offset with `tool`). A model with an effect
    that reads the temperature or payload is evaluated at the middle of the range it was
    fitted on (`FitResult.conditions`; 20 degC, 0 kg when not recorded)."""
    from torchcal.calibration.accuracy import predicted_sigma

    P = res.model.n_params
    fb = torch.cat([torch.arange(sl.start, sl.stop) for sl in frame_slices(res.model, tool)])
    c = torch.zeros(P, P, dtype=torch.float64)
    c[fb[:, None], fb[None, :]] = res.covariance.cov.detach().to("cpu", torch.float64)[fb[:, None], fb[None, :]]
    at = {k: torch.full((poses.shape[0],), sum(v) / 2, dtype=res.theta.dtype, device=res.theta.device)
          for k, v in (getattr(res, "conditions", None) or {}).items()}
    at.setdefault("temp_c", torch.full((poses.shape[0],), 20.0, dtype=res.theta.dtype, device=res.theta.device))
    return predicted_sigma(res.model, res.theta, c.to(res.theta), poses.to(res.theta), at.get("payload_kg"),
                           at["temp_c"]).detach().cpu()


def undetermined_frame(res, poses: torch.Tensor, training_rms_mm: float | None, tool: bool = False,
                       factor: float = FAR_FACTOR) -> str | None:
    """The warning line when a registration leaves the frame undetermined (None otherwise):
    the 1-sigma its frame (and tool) uncertainty alone gives the model's positions at
    `poses` (K, n) (the model's calibration poses, spread over its calibrated joint range)
    exceeds `factor` times the training rms (1 mm without one). A registration on a few
    poses, or on poses where a joint barely moves (the tool offset along it then trades
    off against the frame), fits its own rows well and the rest of the workspace badly:
    `register --tool` on 100 UR10 poses with joint 6 still put the frame 68 mm off."""
    if res.covariance is None or poses is None or poses.shape[0] == 0:
        return None
    s = frame_uncertainty(res, poses, tool)
    bound = factor * training_rms_mm if training_rms_mm and training_rms_mm > 0 else 1.0
    worst = float(s.max())
    if not worst > bound:
        return None
    what = "measuring frame and tool offset" if tool else "measuring frame"
    return (f"the registration on {res.registration['n']} rows leaves the {what} undetermined: the model's "
            f"positions over its calibrated workspace are uncertain by up to {worst:.3g} mm (1 sigma; median "
            f"{float(s.median()):.3g} mm) from it alone, above {bound:.3g} mm (warning above "
            f"{factor:g}x the training rms): measure more poses, spread over every joint")


def _base_slice(model):
    for e, sl in zip(model.effects, model.slices[1:]):
        if e.name == "base_frame":
            return sl
    return None


def frame_summary(R: torch.Tensor, t: torch.Tensor) -> dict:
    """{"translation_mm": [x, y, z], "rotation_fixed_xyz_deg": [rx, ry, rz]} (R = Rz Ry Rx)."""
    ang = torch.rad2deg(matrix_to_fixed_xyz(R.detach().cpu().double()))
    return {"translation_mm": [float(v) for v in t.detach().cpu()],
            "rotation_fixed_xyz_deg": [float(v) for v in ang]}


def base_frame_summary(model, theta: torch.Tensor) -> dict | None:
    """The fitted base frame (measurement <- robot base) in mm and fixed-XYZ degrees, or
    None when the model has no base_frame effect."""
    sl = _base_slice(model)
    if sl is None:
        return None
    p = theta[sl].detach().cpu().double()
    return frame_summary(rotvec_to_matrix(p[3:6]), p[:3])


def register_frame(model, ctx, xyz: torch.Tensor, theta0: torch.Tensor | None = None):
    """Closed-form registration of the model at theta0 (default zeros) to measured xyz (N, 3).

    Returns (theta (P,), info): theta is theta0 with the base_frame parameters set to the
    rigid motion measured <- model (unchanged when the model has no base_frame); info
    holds "rms_before_mm" (model as is), "rms_after_mm" (after the rigid motion) and the
    frame ("translation_mm", "rotation_fixed_xyz_deg").
    """
    theta = model.zeros() if theta0 is None else theta0.detach().clone()
    sl = _base_slice(model)
    if sl is not None:
        theta[sl] = 0.0
    with torch.no_grad():
        v = model.predict(theta, ctx)
    R, t = kabsch(v, xyz)
    before = float((v - xyz).norm(dim=-1).pow(2).mean().sqrt())
    after = float((v @ R.T + t - xyz).norm(dim=-1).pow(2).mean().sqrt())
    if sl is not None:
        theta[sl] = torch.cat([t, matrix_to_rotvec(R)]).to(theta)
    info = {"rms_before_mm": before, "rms_after_mm": after, **frame_summary(R, t)}
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (float(torch.trace(R)) - 1) / 2))))
    info["rotation_angle_deg"] = angle
    return theta, info


def frame_slices(model, tool: bool = False) -> list:
    """Slices of theta (P,) that carry the measuring frame: base_frame, and tool_offset
    when `tool`."""
    names = ("base_frame", "tool_offset") if tool else ("base_frame",)
    return [sl for e, sl in zip(model.effects, model.slices[1:]) if e.name in names]


def with_frame(model, theta: torch.Tensor, tool: bool = False):
    """(model, theta) with base_frame (and tool_offset when `tool`) among the effects:
    the model itself, or a copy with the missing effects appended at zero (the other
    parameters keep their places)."""
    from torchcal.calibration.model import CalibrationModel

    have = {e.name for e in model.effects}
    add = [n for n in (("base_frame", "tool_offset") if tool else ("base_frame",)) if n not in have]
    if not add:
        return model, theta
    new = CalibrationModel(model.robot, [*model.effects, *add], points=model.points or model.point_ids or None)
    return new, torch.cat([theta, theta.new_zeros(new.n_params - theta.shape[0])])


def reregister(model, theta: torch.Tensor, ctx, xyz: torch.Tensor, *, tool: bool = False, pose=None,
               covariance=None, identified=None, q_range=None, conditions=None):
    """Re-estimate only the measuring frame of a fitted model on new measurements.

    model, theta (P,): the fitted model; ctx, xyz (N, 3) mm: the new measurements (their
    context). The base frame (and the tool offset when `tool`) starts at the closed-form
    `register_frame` and is refined by Levenberg-Marquardt with every other parameter fixed;
    a model without base_frame (or tool_offset) gets it appended. covariance: the
    model's `ParameterCovariance` (None: unknown); its rows and columns of the frame are
    replaced by the registration's own estimate (no cross terms: the frame is estimated
    from other data). identified: (P,) bool identified parameters of the model (default:
    nonzero variance, else its default free set). q_range: the calibrated joint range
    (2, n), and conditions: the temperature / payload range the model was fitted on
    (`FitResult.conditions`), kept (not those of the registration data).

    Returns a `FitResult` on the registration data: ``registration`` holds
    "rms_before_mm" (the model as it was), "closed_form_rms_mm", "rms_after_mm" and the
    frame; ``rms_mm`` is the error on these data.
    """
    import dataclasses

    from torchcal.calibration.fit import fit
    from torchcal.calibration.covariance import ParameterCovariance

    P0 = theta.shape[0]
    model, theta = with_frame(model, theta.detach().to(xyz), tool)
    with torch.no_grad():
        before = float((model.predict(theta, ctx) - xyz).norm(dim=-1).pow(2).mean().sqrt())
    start, info = register_frame(model, ctx, xyz, theta)
    free = torch.zeros(model.n_params, dtype=torch.bool)
    for sl in frame_slices(model, tool):
        free[sl] = True
    res = fit(model, ctx, xyz, theta0=start, free=free, pose=pose, register=False,
              max_length_mm=None, max_angle_deg=None)
    if identified is None:
        identified = (torch.diagonal(covariance.cov) > 0) if covariance is not None else \
            model.default_free()[:P0]
    ident = torch.zeros(model.n_params, dtype=torch.bool)
    ident[:P0] = torch.as_tensor(identified, dtype=torch.bool).cpu()
    ident[free] = res.report.free[free]
    cov = res.covariance
    if covariance is not None:
        c = torch.zeros(model.n_params, model.n_params, dtype=torch.float64)
        c[:P0, :P0] = covariance.cov.detach().to("cpu", torch.float64)
        c[free, :] = 0.0
        c[:, free] = 0.0
        fb = free.nonzero().flatten()
        c[fb[:, None], fb[None, :]] = res.covariance.cov.detach().to("cpu", torch.float64)[fb[:, None], fb[None, :]]
        cov = dataclasses.replace(covariance, cov=c.to(theta))
    info = {"rms_before_mm": before, "closed_form_rms_mm": info["rms_after_mm"], "rms_after_mm": res.rms_mm,
            **base_frame_summary(model, res.theta), "n": int(xyz.shape[0]), "tool": bool(tool)}
    return dataclasses.replace(res, std=cov.std, covariance=cov, report=dataclasses.replace(res.report, free=ident),
                               registration=info, q_range=q_range, conditions=conditions, plausible_limits=None,
                               implausible=[])

