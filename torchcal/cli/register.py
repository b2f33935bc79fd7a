"""`torchcal register DATA --model MODEL.json --out NEW.json [--tool]`: move a fitted model to
a new set-up (a moved laser tracker, a new measuring frame) by re-estimating only the
measuring frame on a few measured poses (torchcal.register).

The base frame (measurement <- robot base), and the tool offset with ``--tool``, start at
the closed-form registration of the model onto DATA and are refined by least squares;
the geometry, the effects, their covariance and the calibrated joint range stay those of
MODEL.json (its "fit" block too: the training RMS the gross-mismatch check compares
with). NEW.json is MODEL.json with the new frame, its uncertainty and a "registration"
block: {"input", "input_sha256", "model", "n", "rms_before_mm", "closed_form_rms_mm",
"rms_after_mm", "translation_mm", "rotation_fixed_xyz_deg", "tool"}.

`torchcal register DATA --robot R --out M.json [--tool]`: a registration-only model, the
nominal robot in its best frame (a baseline before any calibration); its calibrated range
is that of DATA. Data that no frame brings near the model are refused (another robot,
units; docs/registration.md). A registered rms above 3x the model's training rms is one
warning line on stderr (exit 0): the model does not carry over to this session; so is a
frame the rows leave undetermined (its own 1-sigma at the model's calibration poses above
3x the training rms: few poses, or a joint that barely moves).
"""

from __future__ import annotations

from torchcal.cli._args import (add_effects_module, add_force, add_robot, add_units, check_outputs, load_robot,
                                read_data, warnings_to_stderr)


def add_parser(sub):
    p = sub.add_parser("register", help="re-estimate only the measuring frame of a model on new poses",
                       description=__doc__.splitlines()[0])
    p.add_argument("data", help="measurement CSV in the new measuring frame")
    p.add_argument("--model", help="MODEL.json from torchcal fit / discover (omit for a registration-only model)")
    add_robot(p, required=False, what="the robot (with --model: check that the model is for it; without: "
                                      "register the nominal robot)")
    p.add_argument("--tool", action="store_true", help="re-estimate the tool offset too")
    p.add_argument("--out", required=True, help="MODEL.json to write")
    add_units(p)
    add_force(p)
    add_effects_module(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from torchcal.api import register
    from torchcal.errors import InputError
    from torchcal.io import modelfile
    from torchcal.io.files import read_json, write_json

    if args.model is None and args.robot is None:
        raise InputError("register: give --model MODEL.json (re-register a fitted model) or --robot R "
                         "(registration-only model)")
    check_outputs([("--out", args.out)], args.force, inputs=[args.data, args.model])
    robot = load_robot(args.robot)
    if args.model is not None:
        fitted = modelfile.load(args.model, robot=robot)
        m = read_data(args.data, fitted.model.robot, args)
        from torchcal.calibration.registration import TransferWarning
        with warnings_to_stderr(TransferWarning):
            res = register(fitted, m, tool=args.tool)
        obj = dict(read_json(args.model, "model file"))
        new = modelfile.to_dict(res)
        for key in ("effects", "parameters", "covariance", "base_frame", "point_ids", "zones"):
            if key in new:
                obj[key] = new[key]
            else:
                obj.pop(key, None)
        what = f"{args.model} ({len(fitted.model.specs())} effects; geometry, effects, covariance and calibrated range kept)"
    else:
        m = read_data(args.data, robot, args)
        res = register(robot, m, tool=args.tool)
        obj = modelfile.to_dict(res, source=args.data, pose_ids=m.pose.tolist())
        what = f"the nominal {robot.name} (registration only)"
    g = res.registration
    obj["registration"] = {"input": str(args.data), "input_sha256": modelfile.file_sha256(args.data),
                           "model": None if args.model is None else str(args.model), **g}
    write_json(args.out, obj, force=args.force, inputs=[args.data, args.model])
    t, r = g["translation_mm"], g["rotation_fixed_xyz_deg"]
    print(f"registered {what} on {g['n']} rows of {args.data}: rms {g['rms_before_mm']:.4g} mm as it was -> "
          f"{g['rms_after_mm']:.4f} mm (closed form {g['closed_form_rms_mm']:.4f} mm)")
    print(f"base frame (measurement <- robot base): translation [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}] mm, "
          f"rotation fixed-XYZ [{r[0]:.4f}, {r[1]:.4f}, {r[2]:.4f}] deg" + ("; tool offset re-estimated" if g["tool"]
                                                                            else ""))
    print(f"wrote {args.out}")
    return 0
