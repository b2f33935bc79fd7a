"""`torchcal fit DATA --robot R [--effects SPEC ...] --out MODEL.json`: geometric model plus
the named effects, fitted by Levenberg-Marquardt; parameters that these poses cannot
identify are named and held at nominal. `--robust huber|cauchy` down-weights gross
outliers by IRLS and lists their pose ids."""

from __future__ import annotations

from torchcal.io import modelfile
from torchcal.cli._args import add_effects_module, add_force, check_outputs, read_data, add_robot
from torchcal.api import fit
from torchcal.io.files import write_json
from torchcal.robots.robot import robot as make_robot
from torchcal.effects.spec import parse_specs


def add_parser(sub):
    p = sub.add_parser("fit", help="fit geometric model + effects to a measurement CSV",
                       description=__doc__)
    p.add_argument("data", help="measurement CSV (docs/design.md)")
    add_robot(p)
    p.add_argument("--effects", nargs="*", default=[], metavar="SPEC", help="effects, e.g. joint_compliance:2,3")
    p.add_argument("--robust", choices=["huber", "cauchy"], help="robust loss by IRLS")
    p.add_argument("--seed", type=int, default=0, help="recorded in the provenance")
    p.add_argument("--out", required=True, help="MODEL.json to write")
    add_force(p)
    add_effects_module(p)
    p.set_defaults(func=run)


def fit_file(args):
    """Read, fit; returns (measurements, FitResult)."""
    robot = make_robot(args.robot)
    specs = [str(s) for s in parse_specs(args.effects, robot.n)] if args.effects else []
    m = read_data(args.data, robot)
    return m, fit(robot, m, specs, robust=args.robust)


def _still_joints(m) -> list[str]:
    """'qJ (constant X deg)' for each joint that never moves in these rows."""
    qd = m.q_deg
    span = (qd.max(0).values - qd.min(0).values).tolist()
    return [f"q{j + 1} (constant {qd[0, j].item():.6g} deg)" for j, s in enumerate(span) if s < 1e-9]


def run(args) -> int:
    check_outputs([("--out", args.out)], args.force, inputs=[args.data])
    m, res = fit_file(args)
    obj = modelfile.to_dict(res, source=args.data, seed=args.seed, robust=args.robust, pose_ids=m.pose.tolist())
    write_json(args.out, obj, force=args.force, inputs=[args.data])
    rep = res.report
    print(f"fit {res.model.robot.name} + [{', '.join(res.model.specs()) or 'geometric only'}] on {len(m)} rows: "
          f"rms {res.rms_mm:.4f} mm, max {float(res.residuals.norm(dim=-1).max()):.4f} mm, "
          f"{rep.rank} identified parameters, condition {rep.condition:.3g}, solver {res.status} "
          f"after {res.n_iter} iterations")
    if rep.held:
        print(f"held at nominal (not identifiable from these poses): {', '.join(rep.held)}")
        still = _still_joints(m)
        if still:
            print(f"joints that never move in {args.data}: {', '.join(still)}; move them to identify more")
    if res.covariance is not None and rep.rank:
        c = res.covariance
        how = (f"pose-level over {len(set(m.pose.tolist()))} poses: noise {c.noise_mm:.4f} mm, "
               f"pose-level error {c.pose_mm:.4f} mm" if c.method == "pose-level" else "rows")
        print(f"parameter uncertainty ({how}; residual sigma {c.sigma_mm:.4f} mm per axis, "
              f"{c.dof} dof); 95% interval by Student's t:")
        for p in obj["parameters"]:
            if p["identified"]:
                print(f"  {p['name']:<16} {p['value']:+.6g} +- {p['std']:.3g} {p['unit']}  "
                      f"[{p['ci95'][0]:+.6g}, {p['ci95'][1]:+.6g}]")
    if res.outliers:
        print(f"outliers (pose ids): {', '.join(map(str, obj['fit']['outlier_poses']))}")
    print(f"wrote {args.out}")
    return 0
