"""`torchcal diagnose DATA --robot R [--model MODEL.json] [--json OUT] [--rrd FILE]`: where
the model fails and which physical effect it is missing (see torchcal.diagnosis.diagnose).
Tracker data (in the instrument's frame, a reflector on the flange) need `--effects
base_frame tool_offset` (or a --model that has them); without them such data are
refused with that cause."""

from __future__ import annotations

from torchcal.cli._args import (add_cv, add_effects_module, add_force, add_units, add_viz, check_folder, check_outputs,
                                read_data, add_robot, robot_inputs)
from torchcal.errors import InputError


def add_parser(sub):
    p = sub.add_parser("diagnose", help="rank the physical effects the model is missing", description=__doc__)
    p.add_argument("data", help="measurement CSV")
    add_robot(p)
    p.add_argument("--model", help="MODEL.json: its effects are the baseline (default geometric only)")
    p.add_argument("--effects", nargs="*", default=None, metavar="SPEC", help="baseline effects (instead of --model); tracker data (in the instrument's frame, a reflector on the flange) need base_frame tool_offset")
    add_cv(p)
    add_sigmas(p)
    p.add_argument("--json", help="write the report here")
    add_viz(p)
    add_units(p)
    add_force(p)
    add_effects_module(p)
    p.set_defaults(func=run)


def add_sigmas(p) -> None:
    """--sigma-mm / --sigma-deg: the orientation weighting of `torchcal fit`, so that diagnose
    and discover fit the rx, ry, rz columns exactly as fit does."""
    from torchcal.defaults import SIGMA_DEG, SIGMA_MM
    from torchcal.cli._args import positive_float

    p.add_argument("--sigma-mm", type=positive_float, default=SIGMA_MM,
                   help=f"position uncertainty of one measurement, mm (default {SIGMA_MM}; as in fit)")
    p.add_argument("--sigma-deg", type=positive_float, default=None,
                   help=f"orientation uncertainty (rx, ry, rz columns), deg (default {SIGMA_DEG}; as in fit; "
                        f"ignored, with a warning, for data without them)")


def print_table(d) -> None:
    rep = d.to_dict()
    b = rep["baseline"]
    print(f"pre-screen (linearised refit, ranks the candidates; current model "
          f"[{', '.join(b['effects']) or 'geometric only'}] max {b['max_mm']:.4f} mm):")
    print(f"{'candidate':<26}{'k':>4}{'rms mm':>10}{'cv rms mm':>11}{'cv gain %':>10}{'score':>8}"
          f"{'p-value':>10}  significant")
    for c in d.candidates[:10]:
        print(f"{c.spec:<26}{c.k:>4}{c.rms_mm:>10.4f}{c.cv_rms_mm:>11.4f}{100 * c.cv_gain:>10.1f}{c.score:>8.2f}"
              f"{c.p_value:>10.2g}  {'yes' if c.significant else 'no'}")
    print("(k: new identifiable parameters; score: held-out log-likelihood gain, nats per pose)")
    worst = max(rep["where"]["per_region"], key=lambda r: r["rms_mm"], default=None)
    if worst:
        print(f"worst region: reach {worst['reach_mm'][0]:.0f}-{worst['reach_mm'][1]:.0f} mm, {worst['z']} half: "
              f"rms {worst['rms_mm']:.4f} mm over {worst['n']} rows")
    print_step(d.step)
    v = d.verdict
    print("verdict: " + ("nothing accepted: no refitted candidate lowers the held-out error beyond chance"
                         if v is None else
                         f"missing {v.spec} (refit cv rms {b['cv_rms_mm']:.4f} -> {d.step.accepted.cv_rms_mm:.4f} mm)"))
    if d.unexplained is not None:
        print(("with the verdict, " if v is not None else "") + d.unexplained.describe())


def print_step(step) -> None:
    """The figures of one step (full refits); `discover` prints the same for each round."""
    for line in step.lines():
        print(line)


def run(args) -> int:
    from torchcal import api
    from torchcal.io import modelfile
    from torchcal.io.files import write_json
    from torchcal.io.robot_file import robot as make_robot

    check_outputs([("--json", args.json), ("--rrd", args.rrd)], args.force,
                  inputs=[args.data, args.model, *robot_inputs(args.robot)])
    check_folder("--plots", args.plots)
    if args.rrd or args.plots:  # the PNG names too, before any work
        from torchcal.cli._viz import check_outputs as check_visual_outputs
        check_visual_outputs(args, "diagnose")
    if args.model and args.effects is not None:
        raise InputError("--model and --effects both give the baseline effects; pass one of them")
    robot = make_robot(args.robot)
    # the baseline effects: the MODEL.json's (checked against --robot) or --effects
    fitted = modelfile.load(args.model, robot=robot) if args.model else None
    effects = fitted.model.specs() if args.model else args.effects or []
    m = read_data(args.data, robot, args)
    from torchcal.calibration.checks.verdict import MismatchWarning
    from torchcal.cli._args import sigma_deg, warnings_to_stderr
    from torchcal.cli._progress import progress
    from torchcal.diagnosis.spectral import NarrowRangeWarning
    with warnings_to_stderr(MismatchWarning, NarrowRangeWarning):  # the model's own frame and error first, then the nominal robot's
        if fitted is not None:
            api.check_diagnosis_data(fitted, fitted.model, m)
        with progress("diagnose", f"screening candidate effects on {len(m)} rows"):
            d = api.diagnose(robot, m, effects, folds=args.folds, seed=args.seed, sigma_mm=args.sigma_mm,
                             sigma_deg=sigma_deg(args, m))
    print_table(d)
    if args.json:
        write_json(args.json, d.to_dict(), force=args.force, inputs=[args.data, args.model])
        print(f"wrote {args.json}")
    if args.rrd or args.plots:
        from torchcal.cli._viz import diagnosis_outputs
        with progress("diagnose", "drawing figures"):
            diagnosis_outputs(args, robot, m, d)
    return 0
