"""A fitted model moved to a new measuring set-up (``torchcal register``): `register_model`.

When the instrument moved, the robot did not: only the measuring frame (and, if asked,
the tool offset) is re-estimated on a few dozen poses of the new set-up
(`torchcal.calibration.registration.reregister`), everything else of the model is kept;
without a model, the nominal robot registered on the rows is the registration-only
baseline (docs/registration.md).
"""

from __future__ import annotations

import torch


def register_model(fitted, robot, m, *, tool: bool = False, stacklevel: int = 1):
    """``torchcal register``: a fitted model `fitted` (`FitResult`) moved to the set-up of
    the measurements `m`, or, with `fitted` None, the registration-only model of `robot`
    (nominal geometry in the best frame, calibrated on these rows). Only the measuring
    frame is estimated (base frame, and the tool offset when `tool`; `reregister`); the
    fitted model keeps its geometry, effects, covariance, calibrated range, settings, tool
    rotation, residual stage and training rms. Data that no frame brings near the model are
    refused (InputError, `torchcal.calibration.checks`); an rms above 3x (`far_from_training`) the
    training rms is a `TransferWarning` (at `stacklevel`, counted from the caller). Data of
    a point id the model was not fitted on (`point_ids_differ`) are refused unless `tool`
    re-estimates a single tool offset (the model then records their point ids). Rows of a
    fitted model outside its calibrated joint range, or at a temperature / payload outside
    the range its effects were fitted on (or without a payload for a model fitted on loads),
    are named as evaluate names them (`CalibratedRangeWarning`, `ConditionRangeWarning`,
    `PayloadAssumedWarning`): there the model extrapolates, and the frame is fitted to it.
    Without `tool`, registered rows beyond 3x the training rms that a tool offset of their
    own would bring within a third are named as another reflector (`ReflectorWarning`,
    `torchcal.calibration.checks.model_data.moved_tool`) in place of the `TransferWarning`."""
    import dataclasses
    import warnings

    from torchcal.calibration.joint_range import joint_range, seed_poses
    from torchcal.calibration.registration import TransferWarning, far_from_training, reregister, undetermined_frame
    from torchcal.calibration.checks.model_data import check_measurements, point_ids_differ
    from torchcal.calibration.checks.verdict import enforce
    from torchcal.calibration.checks.ranges import payload_conditions, warn_outside_conditions, warn_outside_range
    from torchcal.calibration.model import CalibrationModel
    from torchcal.effects import context_of
    from torchcal.errors import InputError

    if fitted is not None:
        cm, theta, train, cov = fitted.model, fitted.theta, fitted.training_rms_mm, fitted.covariance
        identified, q_range, conditions = fitted.report.free, fitted.q_range, getattr(fitted, "conditions", None)
        other = point_ids_differ(cm, m)  # another reflector: its tool offset must be estimated again
        if other is not None and (cm.points or not tool):
            raise InputError(other, fix=None if cm.points else ("tool", True))
        if other is not None:  # re-estimated on these data: the model is now theirs
            cm = CalibrationModel(cm.robot, list(cm.effects), points=sorted(set(m.point.tolist())))
    else:  # registration only: the nominal robot, calibrated on these rows
        cm = CalibrationModel.for_measurements(robot, ["base_frame"] + (["tool_offset"] if tool else []), m)
        theta, identified, q_range = cm.zeros(), torch.zeros(cm.n_params, dtype=torch.bool), joint_range(m.q)
        conditions = None  # a frame and a tool offset read no condition
        train, cov = None, None
    ctx = context_of(cm.robot, m)
    cm.check_context(ctx)
    if len(m) < 3:
        raise InputError(f"{m.source or 'measurements'}: registration needs at least 3 rows, got {len(m)}")
    if fitted is not None:  # rows where the model extrapolates: the frame is fitted to its extrapolation there
        ranges = payload_conditions(fitted, m.payload_kg, m.source or "data", "registered at", stacklevel + 1)
        warn_outside_conditions(ranges, {"temp_c": ctx.temp_c, "payload_kg": ctx.payload_kg}, "registration rows",
                                stacklevel=stacklevel + 1)
        warn_outside_range(m.q, q_range, cm.robot, "registration rows", fitted.residual_model,
                           stacklevel=stacklevel + 1)
    res = reregister(cm, theta.to(m.xyz), ctx, m.xyz, tool=tool, pose=m.pose, covariance=cov,
                     identified=identified, q_range=q_range, conditions=conditions)
    enforce(check_measurements(res.model, res.theta, m, train, q_range=q_range))  # still off: another robot, units
    far = far_from_training(res.rms_mm, train)
    if far is not None and not tool and (m.point is None or len(set(m.point.tolist())) == 1):
        from torchcal.calibration.checks.model_data import ReflectorWarning, moved_tool

        with torch.no_grad():  # the rows of another reflector than the model's, rather than terms of a session?
            err = m.xyz - res.predict(ctx)
            other_tool = moved_tool(res.rms_mm, err, res.model.predict_rotation(res.theta, ctx), train,
                                    m.source or "data")
        if other_tool is not None:
            warnings.warn(other_tool, ReflectorWarning, stacklevel=stacklevel + 1)
            far = None
    if far is not None:
        warnings.warn(far, TransferWarning, stacklevel=stacklevel + 1)
    poses = fitted.seed_poses if fitted is not None and fitted.seed_poses is not None else seed_poses(m.q)
    loose = undetermined_frame(res, poses, train, tool)
    if loose is not None:
        warnings.warn(loose, TransferWarning, stacklevel=stacklevel + 1)
    if fitted is None:
        return res
    f = fitted
    out = dataclasses.replace(res, orientation=f.orientation, robust=f.robust, sigma_mm=f.sigma_mm,
                              sigma_deg=f.sigma_deg, seed_poses=f.seed_poses, residual_model=f.residual_model,
                              training=f.training, provenance=f.provenance, set_by_prior=f.set_by_prior,
                              residual_test=f.residual_test)
    return out if not hasattr(f, "zones") else zones_moved(f, out, tool)


def zones_moved(zoned, reg, tool: bool):
    """The `ZonedFit` `zoned` in the set-up of its registered global fit `reg` (a
    `FitResult` of the same model): every zone's measuring frame takes the global frame's
    rigid change, new <- old, ``T = B_reg B_old^-1`` (a zone's base frame B_z becomes T B_z:
    each zone predicts in the new frame exactly what it predicted in the old), and with
    `tool` every zone's tool offset the global one's change; each zone keeps everything
    else. A zoned model without a base_frame (or, with `tool`, a tool_offset) effect is
    refused (InputError): its zones have no frame to move."""
    import dataclasses

    from torchcal.calibration.registration import frame_slices
    from torchcal.calibration.zone_calibration import ZonedFit
    from torchcal.errors import InputError
    from torchcal.rotations import matrix_to_rotvec, rotvec_to_matrix

    if reg.model.n_params != zoned.model.n_params:
        need = "base_frame and tool_offset" if tool else "base_frame"
        raise InputError(f"register: a per-zone model needs {need} among its effects to be moved to a new set-up "
                         f"(its effects: {', '.join(zoned.model.specs()) or 'none'}); calibrate it with them")
    base = next(sl for e, sl in zip(reg.model.effects, reg.model.slices[1:]) if e.name == "base_frame")
    tools = [sl for sl in frame_slices(reg.model, tool) if sl != base]

    def frame(theta):  # (R (3, 3), t (3,) mm): measuring <- robot base
        return rotvec_to_matrix(theta[base][3:6]), theta[base][:3]

    old = zoned.theta.to(reg.theta)
    (R0, t0), (R1, t1) = frame(old), frame(reg.theta)
    RT = R1 @ R0.T
    tT = t1 - RT @ t0
    zones = []
    for z in zoned.zones:
        th = z.theta.to(reg.theta).clone()
        Rz, tz = frame(th)
        th[base] = torch.cat([RT @ tz + tT, matrix_to_rotvec(RT @ Rz)])
        for sl in tools:
            th[sl] = th[sl] + reg.theta[sl] - old[sl]
        zones.append(dataclasses.replace(z, model=reg.model, theta=th))
    return ZonedFit.of(reg, zones, zoned.partition, zoned.method, zoned.zone_poses)
