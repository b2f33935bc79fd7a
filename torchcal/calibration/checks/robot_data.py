"""Measurements against the nominal robot, before a fit (`check_robot_data`,
`check_robot_data_of`, `check_diagnosis_data`), and a fit's own residuals after it
(`check_fitted`).

The nominal robot with its measuring frame and tool offset fitted (`frame_fit`) must come
within GROSS_MM of the data, else the cause is named: a frame the model lacks, gross
outlier rows, a mirrored frame, reversed joint columns, two sessions joined or the
instrument or reflector changed midway through one session (`sessions`), one joint column
mixed up or positions a few rows off (`columns`), rx, ry, rz in another convention
(`orientation`), another robot or units; a fitted RMS beyond GROSS_MM (the robust fit's
outliers left out) is no calibration (docs/registration.md).
"""

from __future__ import annotations

import math

import torch

from torchcal.calibration.checks.columns import column_hint, lag_words, reordered, row_lag
from torchcal.calibration.checks.frame_fit import fits_in_a_frame, in_frame, quick_rms, registered
from torchcal.calibration.checks.model_data import check_measurements, check_points
from torchcal.calibration.checks.orientation import orientation_mismatch
from torchcal.calibration.checks.point_swap import message as swap_message, swapped_before_fit
from torchcal.calibration.checks.robot_table import length_typo, proximal_table
from torchcal.calibration.checks.sessions import changed_midway, joined_sessions, moved_within_gross
from torchcal.calibration.checks.units import spread_mm, units_hint
from torchcal.calibration.checks.verdict import GROSS_MM, OUTLIER_SHARE, Mismatch, enforce, listed, rms_of
from torchcal.errors import InputError


def check_robot_data(model, m, robust: bool | None = False) -> Mismatch | None:
    """Can the measurements `m` (`Measurements`) come from `model`'s robot at all? Judged
    before a fit (nominal geometry, every parameter at zero) against GROSS_MM, the
    plausible error of an uncalibrated arm. Returns None (consistent, or too few rows to
    judge) or a `Mismatch` whose verdict names the cause:

    - 'frame': the robot in its best measuring frame with its best tool offset fits, with
      the frame effects the model has (base_frame, tool_offset, or none) it does not (a
      tracker's frame, a reflector on the flange);
    - 'outliers' (not when `robust` is True, a robust fit follows): at most OUTLIER_SHARE
      of the rows lie beyond the bound and the frame refitted on the others fits them;
      with robust False the fix is ``robust='huber'``, with None (a command without a
      robust loss) none;
    - 'mirrored': the data with one axis negated fit (a rigid motion with a reflection,
      e.g. two of x, y, z swapped; a proper rigid motion does not);
    - 'reversed': the data with the joint columns in reverse order fit;
    - 'mismatch': none of these (another robot, or units: the spread ratio's hint).
    """
    import dataclasses

    from torchcal.effects import context_of
    what = m.source or "data"
    name = model.robot.name
    try:
        ctx = context_of(model.robot, m)
        model.check_context(ctx)
        quick = quick_rms(model, ctx, m.xyz)
        if quick <= GROSS_MM:
            return moved_within_gross(model, m, quick)
        pred = registered(model, m)
    except InputError:
        return None  # too few rows, missing columns: the fit says it in its own words
    d = (pred - m.xyz).norm(dim=-1)
    reg = rms_of(d)
    have = [e.name for e in model.effects]
    missing = [n for n in ("base_frame", "tool_offset") if n not in have]

    def result(verdict, msg, fix=None, rms=reg):
        return dataclasses.replace(check_points(pred, m.xyz, None, what), rms_mm=rms, registered_rms_mm=reg,
                                   verdict=verdict, message=msg, fix=fix)

    if reg <= GROSS_MM:
        as_is = reg if not missing else rms_of((in_frame(model, m) - m.xyz).norm(dim=-1))
        if as_is <= GROSS_MM:
            return moved_within_gross(model, m, reg, pred)
        return result("frame", f"{what}: the measurements are in another frame: the nominal {name} is off by rms "
                      f"{as_is:.4g} mm with the effects given and by {reg:.4g} mm with a fitted measuring frame and "
                      f"tool offset, which the model lacks (tracker data need base_frame tool_offset; data in the "
                      f"robot's base frame with its nominal tool need neither)",
                      ("effects", [*model.specs(), *missing]), as_is)
    n = d.shape[0]
    keep = d <= max(GROSS_MM, 3 * float(d.median()))
    n_far = n - int(keep.sum())
    if n_far <= OUTLIER_SHARE * n and int(keep.sum()) >= 3:
        sub = m.subset(keep.nonzero().flatten())
        try:
            inlier_rms = rms_of((registered(model, sub) - sub.xyz).norm(dim=-1))
        except InputError:
            inlier_rms = math.inf
        if inlier_rms <= GROSS_MM:
            if robust:
                return None
            far = (~keep).nonzero().flatten().tolist()
            ids = listed(int(m.pose[i]) for i in far)
            return result("outliers", f"{what}: {n_far} of {n} rows (pose ids {ids}) lie {float(d[~keep].min()):.4g}"
                          f" to {float(d.max()):.4g} mm off the nominal {name} in its best frame while the others "
                          f"agree to rms {inlier_rms:.4g} mm: gross outliers (mis-typed or corrupted rows) would "
                          "pull the fit; remove them, or fit with a robust loss (it names them)",
                          None if robust is None else ("robust", "huber"))
    flipped_xyz = m.xyz * torch.tensor([-1.0, 1.0, 1.0], dtype=m.xyz.dtype, device=m.xyz.device)
    if fits_in_a_frame(model, dataclasses.replace(m, xyz=flipped_xyz)):
        return result("mirrored", f"{what}: a mirror image of {name}: rms {reg:.4g} mm after the best rigid motion, "
                      f"but within {GROSS_MM:g} mm after one with a reflection; the x, y, z columns describe a "
                      "left-handed frame (two of them swapped, or one negated)")
    backwards = reordered(m.q, model.robot.prismatic, range(model.robot.n - 1, -1, -1))  # each value in its unit
    if model.robot.n > 1 and fits_in_a_frame(model, dataclasses.replace(m, q=backwards, q_prev=None)):
        return result("reversed", f"{what}: the joint columns are in reverse order: rms {reg:.4g} mm as given "
                      f"but within {GROSS_MM:g} mm with q{model.robot.n} .. q1 read as q1 .. q{model.robot.n}")
    def kabsch_rms(mm):  # the nominal robot rigidly moved onto the data: no solve
        from torchcal.rotations import kabsch

        with torch.no_grad():
            p = model.predict(model.zeros().to(mm.xyz), context_of(model.robot, mm))
        R, t = kabsch(p, mm.xyz)
        return rms_of((p @ R.T + t - mm.xyz).norm(dim=-1))

    def fits(mm):  # the nominal robot in a frame of its own: within GROSS_MM
        return fits_in_a_frame(model, mm)

    join = joined_sessions(m, fits)
    if join is not None:
        return result("mismatch", f"{what}: cannot come from {name} in one measuring frame: rms {reg:.4g} mm with the "
                      f"best frame and tool offset, but rows 1..{join} and {join + 1}..{len(m)} (data rows; pose ids "
                      f"restart at {int(m.pose[join])}) each fit within {GROSS_MM:g} mm in a frame of their own: two "
                      "sessions joined, the instrument moved between them; calibrate on one, or register each "
                      "(torchcal register)")
    lag = row_lag(m, fits)
    change = None if lag is not None else changed_midway(m, fits)
    if change is not None:
        at = f"data row {change + 1} (pose id {int(m.pose[change])})"
        return result("mismatch", f"{what}: cannot come from {name} in one measuring frame with one tool: rms "
                      f"{reg:.4g} mm with the best frame and tool offset, but rows 1..{change} and {change + 1}.."
                      f"{len(m)} each fit within {GROSS_MM:g} mm in a frame and with a tool offset of their own: the "
                      f"instrument moved or the reflector was changed midway, by {at} at the latest; give the rows "
                      "from the change a point id of their own (another reflector), or calibrate on one part and "
                      "register the other (torchcal register)")
    if lag is not None:
        return result("mismatch", f"{what}: cannot come from {name} as given: rms {reg:.4g} mm with the best measuring "
                      f"frame and tool offset, but within {GROSS_MM:g} mm with {lag_words(lag)}")
    hint = column_hint(m, model.robot, fits, score=kabsch_rms)
    if hint is not None:
        return result("mismatch", f"{what}: cannot come from {name} as given: rms {reg:.4g} mm with the best measuring "
                      f"frame and tool offset, but within {GROSS_MM:g} mm with the joint {hint}: check the "
                      "joint columns")
    typo = length_typo(model, m)
    if typo is not None:
        (j, key, was, best), twins = typo[0], typo[1:]
        alike = (" (or " + ", ".join(f"joints[{j2}].{k2} {b2:.1f} instead of {w2:g}" for j2, k2, w2, b2 in twins)
                 + ": they move the points alike)") if twins else ""
        return result("mismatch", f"{what}: cannot come from {name} as given: rms {reg:.4g} mm with the best measuring "
                      f"frame and tool offset, but within {GROSS_MM:g} mm with the robot file's joints[{j}].{key} "
                      f"{best:.1f} instead of {was:g}{alike}: a length mistyped in the robot file, or another "
                      f"variant of the robot; check {'these lengths' if twins else 'that length'} against the data "
                      "sheet")
    if proximal_table(model, m):
        return result("mismatch", f"{what}: cannot come from {name} as given: rms {reg:.4g} mm with the best measuring "
                      f"frame and tool offset, but within {GROSS_MM:g} mm with the robot file's a_mm and alpha_deg "
                      "moved up one row: its table is in Craig's modified D-H convention (row i holding a and alpha "
                      "of the link before joint i); torchcal's row i holds the link after joint i, Rz(theta) Tz(d) "
                      "Tx(a) Rx(alpha) (docs/robots.md): move each row's a_mm and alpha_deg up one row (the last "
                      "row's become 0, the first row's go into base)")
    s_x, s_p = spread_mm(m.xyz), spread_mm(pred)
    causes = "data of another robot or units (length or angle unit)"
    if abs(math.log(max(s_x, 1e-12) / max(s_p, 1e-12))) < math.log(1.1):  # the same size: no unit mistake
        causes = ("the spreads agree within 10 %, so no unit: data of another robot of that size, or many "
                  f"corrupted rows (more than the {OUTLIER_SHARE:.0%} a robust fit sets aside)")
    return result("mismatch", f"{what}: cannot come from {name}: rms {reg:.4g} mm with the best measuring frame "
                  f"and tool offset, point spread {s_x:.4g} mm measured vs {s_p:.4g} mm modelled; likely causes: "
                  f"{causes}{units_hint(s_x / max(s_p, 1e-12))}")


def check_fitted(residuals: torch.Tensor, outliers=(), what: str = "data", name: str = "the model") -> str | None:
    """After a fit: None, or one line when its residuals (N, 3) mm, the rows in `outliers`
    (0-based, the robust fit's) left out, have an RMS beyond GROSS_MM: no calibration of
    this robot is that far off, so nothing sensible was fitted."""
    keep = torch.ones(residuals.shape[0], dtype=torch.bool)
    keep[list(outliers)] = False
    rms = rms_of(residuals.detach().cpu()[keep].norm(dim=-1))
    if rms <= GROSS_MM:
        return None
    return (f"{what}: the fitted model of {name} is still off by rms {rms:.4g} mm (a calibrated arm is off by less "
            f"than {GROSS_MM:g} mm): nothing sensible was fitted; likely causes: data of another robot, units, "
            "joint columns in another order, a mirrored frame, gross outliers (a robust loss), or a measuring "
            "frame the model lacks (the effects base_frame tool_offset)")


def check_robot_data_of(model, m, robust: bool | None = None):
    """Refuse (InputError, one line naming the cause) measurements `m` that the nominal
    robot of `model` cannot explain, or that need a measuring frame the model lacks
    (`check_robot_data`; robust: True when a robust fit follows, False for a fit without,
    None for a command without a robust loss), or whose rx, ry, rz do not describe its tool
    (`orientation_mismatch`); fit, diagnose and discover call it."""
    found = check_robot_data(model, m, robust=robust)
    if found is not None:
        try:
            return enforce(found)
        except InputError:
            named = swapped_before_fit(model, m)  # reflectors' ids exchanged look like outliers or two sessions
            if named:
                raise InputError(swap_message(m, named) + " Correct the point column") from None
            raise
    msg = orientation_mismatch(model, m)
    if msg is not None:
        raise InputError(msg)
    return None


def check_diagnosis_data(robot_or_model, model, m):
    """The gross-mismatch check of `diagnose`: a fitted model (`FitResult`) as it is (a moved
    frame only warns: the diagnosis refits it), else the nominal robot of `model`
    (`CalibrationModel`) with the frame effects it has (`check_robot_data_of`)."""
    from torchcal.calibration.fit import FitResult
    from torchcal.calibration.model import CalibrationModel

    if isinstance(robot_or_model, FitResult):
        res = check_measurements(model, robot_or_model.theta, m, robot_or_model.training_rms_mm,
                                 q_range=robot_or_model.q_range)
        return enforce(res, refuse_frame=False, refuse_mismatch=True)
    return check_robot_data_of(CalibrationModel.for_measurements(model.robot, model.specs(), m), m)
