"""Predicted TCP accuracy of a fitted model over the workspace (``torchcal accuracy``).

At N workspace poses (Latin hypercube inside the joint range the model was calibrated on,
or inside the joint limits on request, filtered like the sweep's workspace,
`torchcal.robots.workspace.sample_workspace`) the parameter covariance C is
propagated through the position Jacobian J: sigma = sqrt(trace J C J^T), the 1-sigma (RMS)
length of the 3-D TCP error that the parameter uncertainty leaves, in mm. It covers what
the fit could not determine, not what the model leaves out.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

__all__ = ["Accuracy", "calibrated_box", "joint1_frame", "predicted_sigma", "region_names", "workspace_accuracy"]


def predicted_sigma(model, theta: torch.Tensor, cov: torch.Tensor, q: torch.Tensor, payload_kg=None,
                    temp_c=None, point=None) -> torch.Tensor:
    """(N,) mm predicted TCP sigma at poses q (N, n) rad of `model` at theta (P,) with the
    parameter covariance cov (P, P); payload_kg, temp_c: (N,) conditions or None; point:
    (N,) reflector ids for a model with one tool offset per point, else None."""
    from torchcal.calibration.covariance import tcp_sigma
    from torchcal.effects import make_context

    ctx = make_context(model.robot, q, payload_kg, temp_c, point=point)
    return tcp_sigma(model.jacobian(theta, ctx), cov)


def joint1_frame(model, theta: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
    """(N, 3) mm: the model's positions pos (N, 3) mm (in its measuring frame) in the
    robot's joint-1 frame (z along joint 1's axis through its origin): undone are the
    model's base_frame at theta (P,) and the robot file's ``base``."""
    from torchcal.calibration.compensate import measuring_from_base

    R, t = measuring_from_base(model, theta)
    B = model.robot.base.to(pos)
    return ((pos - t) @ R - B[:3, 3]) @ B[:3, :3]


def region_names(q: torch.Tensor, pos: torch.Tensor) -> list[str]:
    """'<sector> / <near|mid-reach|far> / <low|mid-height|high>' per pose: the joint-1 angle
    of q (N, n) rad in four sectors (front -45..45 deg, left, back, right), the reach of pos
    (N, 3) mm in the joint-1 frame (`joint1_frame`) from the joint-1 axis and its height
    along it, by tertiles of the sample."""
    a = torch.rad2deg(q[:, 0])
    sector = ["front" if abs(v) <= 45 else "left" if 45 < v <= 135 else "right" if -135 <= v < -45
              else "back" for v in a.tolist()]

    def tert(x, names):
        lo, hi = torch.quantile(x, torch.tensor([1 / 3, 2 / 3], dtype=x.dtype)).tolist()
        return [names[0] if v < lo else names[1] if v < hi else names[2] for v in x.tolist()]
    reach = tert(pos[:, :2].norm(dim=-1), ("near", "mid-reach", "far"))
    height = tert(pos[:, 2], ("low", "mid-height", "high"))
    return [f"{s} / {r} / {h}" for s, r, h in zip(sector, reach, height)]


@dataclass
class Accuracy:
    """Predicted accuracy at sampled workspace poses.

    q: (N, n) rad poses; pos: (N, 3) mm model positions (its measuring frame); sigma: (N,) mm predicted TCP sigma;
    regions: (region, mean sigma mm, max sigma mm, points) of the regions with >= 5 points,
    worst mean first; seed: the sample's seed; robot, effects: the model's robot name and effect specs;
    points: the reflector ids of a model with one tool offset per point (sigma: the largest
    of theirs at each pose; pos: the first's), else ();
    q_range: (2, n) rad / mm the joint range the model was calibrated on (None: not recorded);
    within: "calibrated" (the poses were drawn inside q_range and the joint limits) or "limits";
    outside: poses beyond q_range (the model extrapolates there; 0 without q_range)."""

    q: torch.Tensor
    pos: torch.Tensor
    sigma: torch.Tensor
    regions: list
    seed: int
    robot: str = ""
    effects: tuple = ()
    q_range: torch.Tensor | None = None
    within: str = "limits"
    outside: int = 0
    points: tuple = ()

    def to_dict(self) -> dict:
        med, p95 = torch.quantile(self.sigma, torch.tensor([0.5, 0.95], dtype=self.sigma.dtype)).tolist()
        return {"robot": self.robot, "effects": list(self.effects), "poses": int(self.q.shape[0]), "seed": self.seed,
                "within": self.within, "outside_calibrated_range": self.outside,
                "sigma_mm": {"min": float(self.sigma.min()), "median": med, "p95": p95,
                             "max": float(self.sigma.max())},
                "regions": [{"region": k, "mean_mm": m, "max_mm": x, "points": c} for k, m, x, c in self.regions]}


class ZoneAccuracyWarning(UserWarning):
    """The accuracy of a per-zone model is that of its global calibration's covariance."""


def zone_accuracy_note(fitted) -> str | None:
    """The warning line for the accuracy of a per-zone model `fitted` (a `ZonedFit`) whose
    zones were fitted each on its own poses (``independent``): its covariance is the global
    calibration's, its zones are less certain, by how much MODEL.json cannot tell (it stores
    no zone covariance). None for any other model (damped zones stay near the global fit)."""
    if getattr(fitted, "method", None) != "independent" or not getattr(fitted, "zones", None):
        return None
    return (f"a per-zone model of {len(fitted.zones)} independent zones (poses {', '.join(map(str, fitted.zone_poses))}): "
            f"these figures are its global calibration's (on all its poses); each zone was fitted on its own poses "
            f"and is less certain, by an amount its MODEL.json cannot tell (it stores no zone covariance): check "
            f"the zones on held-out poses (evaluate)")


def calibrated_box(robot, q_range: torch.Tensor) -> torch.Tensor:
    """(n, 2) rad / mm: the joint limits of `robot` narrowed to q_range (2, n), the joint
    range a model was calibrated on; InputError where the two do not overlap."""
    from torchcal.errors import InputError

    lim = robot.limits
    box = torch.stack([torch.maximum(lim[:, 0], q_range[0].to(lim)), torch.minimum(lim[:, 1], q_range[1].to(lim))], 1)
    if bool((box[:, 0] > box[:, 1]).any()):
        bad = [i + 1 for i in range(robot.n) if box[i, 0] > box[i, 1]]
        raise InputError(f"the calibrated joint range lies outside the joint limits at joint(s) "
                         f"{', '.join(map(str, bad))}")
    return box


def workspace_accuracy(model, theta: torch.Tensor, cov: torch.Tensor, *, n: int = 2000, seed: int = 0,
                       payload_kg: float | None = None, temp_c: float = 20.0, q_range: torch.Tensor | None = None,
                       within: str = "calibrated", conditions: dict | None = None) -> Accuracy:
    """The `Accuracy` of `model` at theta (P,) with covariance cov (P, P) at n workspace poses
    drawn with `seed`; payload_kg (default: half the rated payload) and temp_c at every pose.
    q_range: (2, n) rad / mm the joint range the model was calibrated on, or None (not
    recorded). within: "calibrated" draws the poses inside q_range (and the limits), where
    the prediction holds; "limits" inside the joint limits, counting those beyond q_range
    (there the model extrapolates). Without q_range the poses come from the limits. A
    temp_c or payload_kg that looks like another unit gets one `ConditionWarning` each
    (`torchcal.measurements.check_conditions_given`); one outside the range `conditions`
    the model was fitted on (FitResult.conditions) one `ConditionRangeWarning`."""
    import dataclasses

    from torchcal.calibration.joint_range import outside_range
    from torchcal.calibration.checks.ranges import warn_outside_conditions
    from torchcal.effects import make_context
    from torchcal.errors import InputError
    from torchcal.robots.workspace import sample_workspace

    from torchcal.measurements import check_conditions_given

    if within not in ("calibrated", "limits"):
        raise InputError(f"within: expected 'calibrated' or 'limits', got {within!r}")
    robot = model.robot
    check_conditions_given(temp_c, payload_kg, robot, "accuracy", stacklevel=3)  # kelvin, grams: one warning each
    if q_range is None:
        within = "limits"
    box = robot if within == "limits" else dataclasses.replace(robot, limits=calibrated_box(robot, q_range))
    q = sample_workspace(box, n, seed=seed)
    outside = 0 if q_range is None else int(outside_range(q, q_range, robot.prismatic).any(-1).sum())
    N = q.shape[0]
    payload = torch.full((N,), robot.payload_kg / 2 if payload_kg is None else payload_kg, dtype=torch.float64)
    temp = torch.full((N,), temp_c, dtype=torch.float64)
    warn_outside_conditions(conditions, {"temp_c": temp, "payload_kg": payload}, "workspace poses", stacklevel=2)
    points = next((tuple(e.points) for e in model.effects if e.name == "tool_offset" and e.points), ())
    ids = [torch.full((N,), p, dtype=torch.int64) for p in points] or [None]  # several reflectors: the worst
    sigma = torch.stack([predicted_sigma(model, theta, cov, q, payload, temp, point=i) for i in ids]).amax(0)
    pos = model.predict(theta, make_context(robot, q, payload, temp, point=ids[0]))
    groups = {}
    for name, s in zip(region_names(q, joint1_frame(model, theta, pos)), sigma.tolist()):
        groups.setdefault(name, []).append(s)
    rows = sorted(((sum(v) / len(v), max(v), len(v), k) for k, v in groups.items() if len(v) >= 5), reverse=True)
    return Accuracy(q, pos, sigma, [(k, m, x, c) for m, x, c, k in rows], seed, robot.name, tuple(model.specs()),
                    q_range, within, outside, points)
