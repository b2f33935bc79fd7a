"""The geometry alone: refit a model's MD-H deviations without the effects a robot file or
a URDF cannot hold, for `torchcal export`.

In a model with physical effects (joint compliance, gear error, backlash, ...) the MD-H
deviations are fitted together with those effects and absorb part of them (a length
deviation takes up part of the compliance's sag). Exported alone, such geometry is worse
than it could be: the controller or simulator that reads the URDF has no effects to add
back. `refit_geometry` starts from the model's geometry (and its base frame and tool
offset, which export folds into the robot's base and tool) and fits that geometry alone
to measurements, so that the exported robot is the best geometry-only robot for those
data. `FOLDED` are the effects a robot file holds; every other effect is dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

FOLDED = ("base_frame", "tool_offset")


@dataclass(frozen=True)
class GeometryRefit:
    """fit: the geometry-only `FitResult` (its model holds the FOLDED effects only);
    full_rms_mm: the full model on the data; naive_rms_mm: the full model's geometry
    without its other effects; refit_rms_mm: the refitted geometry (mm, on the same data);
    dropped: specs of the effects left out."""

    fit: object
    full_rms_mm: float
    naive_rms_mm: float
    refit_rms_mm: float
    dropped: list


def geometry_model(model, theta: torch.Tensor):
    """(geometry-only CalibrationModel, its theta (P',), index (P',) of its parameters in
    `model`'s): the MD-H deviations and the FOLDED effects of `model` at their values in
    theta (P,)."""
    from torchcal.calibration.model import CalibrationModel

    keep = [(e, sl) for e, sl in zip(model.effects, model.slices[1:]) if e.name in FOLDED]
    geo = CalibrationModel(model.robot, [e for e, _ in keep])
    geo.points = model.points
    idx = torch.cat([torch.arange(model.slices[0].start, model.slices[0].stop),
                     *[torch.arange(sl.start, sl.stop) for _, sl in keep]])
    return geo, theta[idx.to(theta.device)], idx


def refit_geometry(model, theta: torch.Tensor, m, *, identified=None, max_iter: int = 60) -> GeometryRefit:
    """Fit the geometry of `model` alone to Measurements m, starting from theta (P,).

    identified: (P,) bool, the parameters the model identified (default its
    `default_free`): the others stay held, so the refit keeps the model's choice among
    dependent parameters (e.g. base_rz or dtheta1). The MD-H deviations beyond the usual
    plausible sizes are held at their start (the model's values), as in every fit
    (`torchcal.calibration.plausibility`)."""
    from torchcal.calibration.fit import fit
    from torchcal.effects import context_of

    ctx = context_of(model.robot, m)
    model.check_context(ctx)
    geo, theta0, idx = geometry_model(model, theta.to(m.xyz))
    free = (model.default_free() if identified is None else torch.as_tensor(identified, dtype=torch.bool).cpu())[idx]

    def rms(mod, th):
        with torch.no_grad():
            return float((mod.predict(th, ctx) - m.xyz).norm(dim=-1).pow(2).mean().sqrt())

    res = fit(geo, ctx, m.xyz, theta0=theta0, free=free, pose=m.pose, register=False, max_iter=max_iter)
    return GeometryRefit(res, rms(model, theta.to(m.xyz)), rms(geo, theta0), res.rms_mm,
                         [e.spec() for e in model.effects if e.name not in FOLDED])


def measuring_frames(model, theta: torch.Tensor):
    """(W (4, 4) or None, reflectors [(name, (3,) mm)]): the model's measuring frame at
    theta (P,) apart from the robot, float64 CPU. W: measuring frame <- robot base frame
    (base_frame), None without it. reflectors: each measured point in the robot's TCP frame
    (its nominal tool, ``tool0``): the tool offset rotated into that frame, named
    ``reflector`` (or ``reflector_ID`` per point id); empty without tool_offset."""
    from torchcal.rotations import rotvec_to_matrix

    theta = theta.to("cpu", torch.float64)
    R_tool = model.robot.tool[:3, :3].to("cpu", torch.float64)
    W, refl = None, []
    for e, sl in zip(model.effects, model.slices[1:]):
        p = theta[sl]
        if e.name == "base_frame":
            W = torch.eye(4, dtype=torch.float64)
            W[:3, :3], W[:3, 3] = rotvec_to_matrix(p[3:6]), p[:3]
        elif e.name == "tool_offset":
            pts = e.points or (None,)
            for k, pid in enumerate(pts):
                refl.append(("reflector" if pid is None else f"reflector_{pid}", R_tool.T @ p[3 * k: 3 * k + 3]))
    return W, refl


def reflector_offsets(model, theta: torch.Tensor) -> list:
    """[{"spec", "parameters"}]: the tool_offset of a model with several reflectors (one
    offset per point id, mm in the flange frame, added to the robot's tool translation)
    at theta (P,), as a robot file lists the effects it does not hold; [] otherwise."""
    theta = theta.to("cpu", torch.float64)
    return [{"spec": e.spec(), "parameters": {n: {"value": float(v), "unit": u} for n, v, u in
                                              zip(e.param_names(), theta[sl].tolist(), e.param_units())}}
            for e, sl in zip(model.effects, model.slices[1:]) if e.name == "tool_offset" and e.points]


def calibrated_robot(model, theta: torch.Tensor, fold: bool = True):
    """(Robot, effects) of a model at theta (P,): the nominal robot (CPU, float64) with the
    MD-H deviations added to its table and, with `fold`, the base_frame effect folded into
    its base (its gravity vector turned into the measuring frame with it) and tool_offset
    into its tool (without: the robot's own base and tool, the
    measuring frame apart, `measuring_frames`); a tool_offset with one offset per point
    (several reflectors) is never folded: one tool cannot hold them (`reflector_offsets`).
    effects: [{"spec", "parameters": {name: {"value", "unit"}}}] of the model's other
    effects, which a robot file, a URDF or an MD-H table cannot hold."""
    import dataclasses

    r = model.robot.to("cpu", torch.float64)
    theta = theta.to("cpu", torch.float64)
    geo = theta[model.slices[0]].reshape(r.n, 5)
    base, tool, gravity = r.base.clone(), r.tool.clone(), r.gravity.clone()
    rest = []
    for e, sl in zip(model.effects, model.slices[1:]):
        p = theta[sl]
        if e.name in FOLDED and not fold:
            continue
        if e.name == "base_frame":  # the world becomes the measuring frame: gravity turns with it
            W = measuring_frames(model, theta)[0]
            base, gravity = W @ base, W[:3, :3] @ gravity
        elif e.name == "tool_offset":
            if not e.points:  # one offset; several (one per reflector): reflector_offsets
                tool[:3, 3] = tool[:3, 3] + p
        else:
            rest.append({"spec": e.spec(), "parameters": {n: {"value": float(v), "unit": u} for n, v, u in
                                                          zip(e.param_names(), p.tolist(), e.param_units())}})
    return dataclasses.replace(r, table=r.table + geo, base=base, tool=tool, gravity=gravity), rest
