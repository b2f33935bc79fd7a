"""`torchcal fit DATA --robot R [--effects SPEC ...] --out MODEL.json`: geometric model plus
the named effects, fitted by Levenberg-Marquardt; parameters that these poses cannot
identify are named and held at nominal. `--robust huber|cauchy` down-weights gross
outliers by IRLS and lists their pose ids.

With `base_frame` among the effects the fit starts from the closed-form registration of
the nominal model onto the measurements (instrument frame), reported as the base frame in
mm and degrees. A data file with a `point` column gets one tool offset per point (needs
`tool_offset`); rx, ry, rz columns add the measured orientation, weighed against position
by --sigma-mm / --sigma-deg. Every parameter has a plausible scale (--max-deviation-mm /
-deg for the MD-H deviations, each effect's range of docs/effects.md): a weak prior
shrinks what the poses barely determine, and what ends beyond its scale is named.

Tracker data (positions in the instrument's frame, a reflector or probe on the flange)
need `--effects base_frame tool_offset`; data in the robot's base frame with its nominal
tool need neither. Data that the nominal robot in no frame can explain are refused
with the likely cause and nothing is written: a frame the effects lack, another robot,
units, a mirrored frame (two of x, y, z swapped), joint columns in reverse order, gross
outlier rows (then --robust), or a fitted rms beyond 10 mm."""

from __future__ import annotations

import math
import sys

from torchcal.cli._args import add_effects_module, add_force, add_units, check_outputs, read_data, add_robot, robot_inputs
from torchcal.cli._args import add_device, device_of, nonneg_float, positive_float, seed_int
from torchcal.defaults import MAX_ANGLE_DEG, MAX_LENGTH_MM, SIGMA_DEG, SIGMA_MM


def add_parser(sub):
    p = sub.add_parser("fit", help="fit geometric model + effects to a measurement CSV",
                       description=__doc__)
    p.add_argument("data", help="measurement CSV (format: docs/formats.md)")
    add_robot(p)
    p.add_argument("--effects", nargs="*", default=[], metavar="SPEC", help="effects, e.g. joint_compliance:2,3; tracker data (in the instrument's frame, a reflector on the flange) need base_frame tool_offset")
    p.add_argument("--robust", choices=["huber", "cauchy"], help="robust loss by IRLS")
    p.add_argument("--seed", type=seed_int, default=0, help="recorded in the provenance")
    p.add_argument("--sigma-mm", type=positive_float, default=SIGMA_MM,
                   help=f"position uncertainty of one measurement, mm (default {SIGMA_MM})")
    p.add_argument("--sigma-deg", type=positive_float, default=None,
                   help=f"orientation uncertainty (rx, ry, rz columns), deg (default {SIGMA_DEG}; "
                        f"ignored, with a warning, for data without them)")
    p.add_argument("--max-deviation-mm", type=nonneg_float, default=MAX_LENGTH_MM,
                   help=f"plausible scale of |dd|, |da| (the prior; default {MAX_LENGTH_MM}; 0 = no prior on dd, da)")
    p.add_argument("--max-deviation-deg", type=nonneg_float, default=MAX_ANGLE_DEG,
                   help=f"plausible scale of |dtheta|, |dalpha|, |dbeta| "
                        f"(default {MAX_ANGLE_DEG}; 0 = no prior on dtheta, dalpha, dbeta)")
    p.add_argument("--residual-model", choices=["kernel"],
                   help="add a non-physical residual stage: kernel ridge of the residual on the joint angles, "
                        "only when its held-out gain is significant; applied by evaluate and compensate, "
                        "dropped by export (docs/residual-model.md)")
    p.add_argument("--out", required=True, help="MODEL.json to write")
    add_units(p)
    add_force(p)
    add_effects_module(p)
    add_device(p, "the fit")
    p.set_defaults(func=run)


def fit_file(args):
    """Read, fit (`torchcal.fit`); returns (measurements, FitResult)."""
    from torchcal.api import fit
    from torchcal.cli._args import sigma_deg, units
    from torchcal.effects.spec import parse_specs
    from torchcal.io.robot_file import robot as make_robot

    device = device_of(args)
    robot = make_robot(args.robot).to(device)
    specs = [str(s) for s in parse_specs(args.effects, robot.n)] if args.effects else []
    m = read_data(args.data, robot, args).to(device)  # the unit check that torchcal.fit repeats, before any warning line
    from torchcal.calibration.checks.row_order import RowOrderWarning
    from torchcal.cli._args import warnings_to_stderr

    opts = dict(robust=args.robust, sigma_mm=args.sigma_mm, sigma_deg=sigma_deg(args, m), **units(args))
    with warnings_to_stderr(RowOrderWarning):  # backlash on rows sorted after the session: one line
        res = fit(robot, m, specs, max_length_mm=args.max_deviation_mm or None,  # 0 drops that prior only
                  max_angle_deg=args.max_deviation_deg or None,
                  residual_model=getattr(args, "residual_model", None), **opts)
    tighter = (0 < args.max_deviation_mm < MAX_LENGTH_MM) or (0 < args.max_deviation_deg < MAX_ANGLE_DEG)
    if tighter:  # what the tighter scales cost: the same fit under the default ones, said in one line
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reference = fit(robot, m, specs, **opts)
        line = prior_cost_line(res, reference)
        if line:
            sys.stderr.write(line + "\n")
    return m, res


def plausibility_line(res) -> str | None:
    """One line naming the parameters that end beyond their plausible scale (the prior
    shrinks them, nothing is held for it), or None. fit, diagnose and discover print it."""
    if not res.implausible:
        return None
    lim = res.plausible_limits or {}
    scales = [f"{lim[k]:g} {u}" for k, u in (("max_length_mm", "mm"), ("max_angle_deg", "deg"))
              if lim.get(k) is not None]
    geo = f"{' / '.join(scales)} for MD-H deviations, " if scales else ""
    return (f"beyond plausible size (shrunk by the prior: {geo}the effects' ranges in docs/effects.md): "
            f"{', '.join(res.implausible)}")


def prior_cost_line(res, reference) -> str | None:
    """One warning line when plausible scales tighter than the defaults visibly cost the fit
    `res` quality against `reference`, the same fit under the default scales
    (`torchcal.calibration.plausibility.prior_cost`): both rms, the parameters the data
    put beyond the given scale and the option that sets it; else None."""
    from torchcal.calibration.plausibility import prior_cost

    cost = prior_cost(res, reference)
    if not cost["costly"]:
        return None
    lim = res.plausible_limits or {}
    words = {"length": f"--max-deviation-mm {lim.get('max_length_mm'):g}", "angle":
             f"--max-deviation-deg {lim.get('max_angle_deg'):g}", "effects": "the effects' ranges in docs/effects.md"}
    held = "; ".join(f"{', '.join(v[:6])}{' ...' if len(v) > 6 else ''} beyond {words[k]}"
                     for k, v in cost["beyond"].items())
    opts = " / ".join(o for k, o in (("length", "--max-deviation-mm"), ("angle", "--max-deviation-deg"))
                      if k in cost["beyond"])
    fix = f"raise {opts} (0: no prior on them)" if opts else "check the effects and the data"
    return (f"torchcal: warning: the plausibility prior costs this fit: rms {cost['rms_mm']:.4f} mm, against "
            f"{cost['reference_rms_mm']:.4f} mm under the default scales ({MAX_LENGTH_MM:g} mm, {MAX_ANGLE_DEG:g} deg); "
            f"the data put {held}: {fix}")


def residual_stage_line(res) -> str:
    """What `--residual-model` did: the stage applied (its held-out test passed) or refused,
    with the figures. fit and discover print it."""
    t, stage = res.residual_test or {}, res.residual_model
    if stage is not None:
        return (f"{stage.describe()}; evaluate and compensate apply it, export drops it\n"
                f"  applied: held-out {t.get('reason', '')}")
    return f"residual stage refused: held-out {t.get('reason', 'test not run')}"


def _still_joints(m) -> list[str]:
    """'qJ (constant X deg)' for each joint that never moves in these rows."""
    qd = m.q_deg
    span = (qd.max(0).values - qd.min(0).values).tolist()
    return [f"q{j + 1} (constant {qd[0, j].item():.6g} deg)" for j, s in enumerate(span) if s < 1e-9]


def _largest(res, k: int = 4) -> str:
    """The k largest fitted MD-H deviations the data determine, readable (mm, deg); those
    the prior sets are no measured deviation and are left out."""

    n5 = 5 * res.model.robot.n
    names, units = res.model.param_names()[:n5], res.model.param_units()[:n5]
    vals = []
    for i in range(n5):
        if not res.report.free[i] or names[i] in res.set_by_prior:
            continue
        v = float(res.theta[i])
        if units[i] == "rad":
            vals.append((abs(math.degrees(v)) / MAX_ANGLE_DEG, f"{names[i]} {math.degrees(v):+.4f} deg"))
        else:
            vals.append((abs(v) / MAX_LENGTH_MM, f"{names[i]} {v:+.4f} mm"))
    return ", ".join(t for _, t in sorted(vals, reverse=True)[:k])


def _stiffness_line(res) -> str | None:
    """The joint stiffness K_J N m/rad that each identified joint_compliance payload term
    (the compliance 1/K_J) gives, or None."""
    names = res.model.param_names()
    out = []
    for e, sl in zip(res.model.effects, res.model.slices[1:]):
        if e.name != "joint_compliance":
            continue
        for j, k in e.stiffness_nm_per_rad(res.theta[sl]).items():
            if bool(res.report.free[names.index(f"compl_{j}_payload")]):
                out.append(f"joint {j} {k:.4g} N m/rad")
    return f"joint stiffness (1 / compliance of the payload term): {', '.join(out)}" if out else None


def _robust_hint(res, robust) -> str | None:
    """One line pointing at --robust when a few rows (at most 5 %) lie beyond 10 x the
    median distance error: gross outliers (corrupted or mis-typed rows) pull a least-squares
    fit; None when robust is already on or nothing stands out."""
    if robust is not None:
        return None
    d = res.residuals.norm(dim=-1)
    med = float(d.median())
    far = int((d > 10 * med).sum())
    if far == 0 or far > max(1, int(0.05 * len(d))):
        return None
    return (f"{far} row(s) with errors beyond 10 x the median (max {float(d.max()):.4g} mm, median {med:.4g} mm): "
            f"gross outliers pull this fit; try --robust huber (it down-weights them and lists their pose ids)")


def run(args) -> int:
    from torchcal.calibration.identifiability import unidentified_lines
    from torchcal.io import modelfile
    from torchcal.io.files import write_json

    device_of(args)  # a refused --device before any work
    check_outputs([("--out", args.out)], args.force, inputs=[args.data, *robot_inputs(args.robot)])
    m, res = fit_file(args)
    obj = modelfile.to_dict(res, source=args.data, seed=args.seed, pose_ids=m.pose.tolist())
    write_json(args.out, obj, force=args.force, inputs=[args.data, *robot_inputs(args.robot)])
    rep = res.report
    print(f"fit {res.model.robot.name} + [{', '.join(res.model.specs()) or 'geometric only'}] on {len(m)} rows: "
          f"rms {res.rms_mm:.4f} mm, max {float(res.residuals.norm(dim=-1).max()):.4f} mm, "
          f"{rep.rank} identified parameters, condition {rep.condition:.3g}, solver {res.status} "
          f"after {res.n_iter} iterations")
    if res.registration is not None:
        g = res.registration
        print(f"registration (closed form, nominal model onto the measurements): rms "
              f"{g['rms_before_mm']:.4g} mm as measured -> {g['rms_after_mm']:.4g} mm registered")
    base = obj.get("base_frame")
    if base is not None:
        t, r = base["translation_mm"], base["rotation_fixed_xyz_deg"]
        print(f"base frame (measurement <- robot base): translation [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}] mm, "
              f"rotation fixed-XYZ [{r[0]:.4f}, {r[1]:.4f}, {r[2]:.4f}] deg (base_rx..base_rz below: the rotation "
              f"vector, axis times angle, not these angles)")
    if res.orientation is not None:
        o = res.orientation
        print(f"orientation: rms {o['rms_deg'] * 1000:.4g} mdeg (weight {math.radians(o['weight_mm_per_rad']):.4g} mm/deg "
              f"from sigma {o['sigma_mm']:g} mm, {o['sigma_deg']:g} deg)")
    held = list(rep.held)
    if held:
        print(f"held at nominal (not identifiable from these poses): {', '.join(held)}")
        still = _still_joints(m)
        if still:
            print(f"joints that never move in {args.data}: {', '.join(still)}; move them to identify more")
        for line in unidentified_lines(res.model, held, m):
            print(line)
    line = plausibility_line(res)
    if line:
        print(line)
    if res.set_by_prior:
        print(f"set by the prior (not determined by these poses: posterior sd at least half the plausible size; "
              f"no measured deviation): {', '.join(res.set_by_prior)}")
    big = _largest(res)
    if big:
        print(f"largest deviations: {big}")
    if res.covariance is not None and rep.rank:
        c = res.covariance
        how = (f"pose-level over {len(set(m.pose.tolist()))} poses: noise {c.noise_mm:.4f} mm, "
               f"pose-level error {c.pose_mm:.4f} mm" if c.method == "pose-level" else "rows")
        print(f"parameter uncertainty ({how}; residual sigma {c.sigma_mm:.4f} mm per axis, "
              f"{c.dof} dof; the plausibility prior included); 95% interval by Student's t:")
        for p in obj["parameters"]:
            if p["identified"]:
                print(f"  {p['name']:<16} {p['value']:+.6g} +- {p['std']:.3g} {p['unit']}  "
                      f"[{p['ci95'][0]:+.6g}, {p['ci95'][1]:+.6g}]" + ("  set by the prior" if p["set_by_prior"] else ""))
    stiff = _stiffness_line(res)
    if stiff:
        print(stiff)
    if getattr(args, "residual_model", None):
        print(residual_stage_line(res))
    if res.outliers:
        print(f"outliers (pose ids): {', '.join(map(str, obj['fit']['outlier_poses']))}")
    hint = _robust_hint(res, args.robust)
    if hint:
        print(hint)
    print(f"wrote {args.out}")
    return 0
