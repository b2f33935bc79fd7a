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
    refused (InputError, `torchcal.calibration.mismatch`); an rms above 3x (`far_from_training`) the
    training rms is a `TransferWarning` (at `stacklevel`, counted from the caller). Data of
    a point id the model was not fitted on (`point_ids_differ`) are refused unless `tool`
    re-estimates a single tool offset (the model then records their point ids)."""
    import dataclasses
    import warnings

    from torchcal.calibration.joint_range import joint_range, seed_poses
    from torchcal.calibration.registration import TransferWarning, far_from_training, reregister, undetermined_frame
    from torchcal.calibration.mismatch import check_measurements, enforce, point_ids_differ
    from torchcal.calibration.model import CalibrationModel
    from torchcal.effects import context_of
    from torchcal.errors import InputError

    if fitted is not None:
        cm, theta, train, cov = fitted.model, fitted.theta, fitted.training_rms_mm, fitted.covariance
        identified, q_range = fitted.report.free, fitted.q_range
        other = point_ids_differ(cm, m)  # another reflector: its tool offset must be estimated again
        if other is not None and (cm.points or not tool):
            raise InputError(other, fix=None if cm.points else ("tool", True))
        if other is not None:  # re-estimated on these data: the model is now theirs
            cm = CalibrationModel(cm.robot, list(cm.effects), points=sorted(set(m.point.tolist())))
    else:  # registration only: the nominal robot, calibrated on these rows
        cm = CalibrationModel.for_measurements(robot, ["base_frame"] + (["tool_offset"] if tool else []), m)
        theta, identified, q_range = cm.zeros(), torch.zeros(cm.n_params, dtype=torch.bool), joint_range(m.q)
        train, cov = None, None
    ctx = context_of(cm.robot, m)
    cm.check_context(ctx)
    if len(m) < 3:
        raise InputError(f"{m.source or 'measurements'}: registration needs at least 3 rows, got {len(m)}")
    res = reregister(cm, theta.to(m.xyz), ctx, m.xyz, tool=tool, pose=m.pose, covariance=cov,
                     identified=identified, q_range=q_range)
    enforce(check_measurements(res.model, res.theta, m, train, q_range=q_range))  # still off: another robot, units
    far = far_from_training(res.rms_mm, train)
    if far is not None:
        warnings.warn(far, TransferWarning, stacklevel=stacklevel + 1)
    poses = fitted.seed_poses if fitted is not None and fitted.seed_poses is not None else seed_poses(m.q)
    loose = undetermined_frame(res, poses, train, tool)
    if loose is not None:
        warnings.warn(loose, TransferWarning, stacklevel=stacklevel + 1)
    if fitted is None:
        return res
    f = fitted
    return dataclasses.replace(res, orientation=f.orientation, robust=f.robust, sigma_mm=f.sigma_mm,
                               sigma_deg=f.sigma_deg, seed_poses=f.seed_poses, residual_model=f.residual_model,
                               training=f.training, provenance=f.provenance, set_by_prior=f.set_by_prior,
                               residual_test=f.residual_test)
