"""Compensation targets against the model (`check_targets`), their seeds (`check_seeds`)
and the conditions they lack (`check_target_conditions`).

Targets (positions (M, 3) mm in the model's frame) against the workspace of the model
(`workspace`): the nominal TCP at `WORKSPACE_POSES` seeded random poses inside the joint
limits, each pushed out by the fitted tool offset's length when the model has one. The
reach R is their largest distance from the robot base origin (as the model's base frame
maps it). Targets whose median distance from the base origin is below R / 20 (the factor
of the unit check, `torchcal.calibration.checks.units`) sit inside the robot's base, or
whose median distance from the origin of the measuring frame (the instrument) is below
R / 20: a unit (a refusal); targets beyond 1.05 R cannot be reached (a warning naming them;
compensate reports them as not converged), unless more than 10 % of them are and a unit
brings them into the workspace (a refusal). The unit is the first of `MISREAD` (metres,
inches) whose factor, applied about the origin of the frame the targets were given in,
puts their median distance from the base within [R / 20, 1.05 R] and at most 10 % of them
beyond 1.05 R ("they look like inches read as mm; convert them to mm (x 25.4)"); the
words and the factor are those of the measurement unit check (`misread_length`).

Seeds of targets: the model at each seed should lie on its target (a seed is the target's
nominal command); seeds within +-2 pi "degrees" a median beyond SEED_MM = 100 mm from
their targets are radians read as degrees (a refusal), other seeds beyond SEED_MM are
named in a warning. Seeds given in radians (the library's ``q0``) beyond what a joint can
turn (`beyond_turn`: max(2 pi, the widest limit) + 0.01 rad) are degrees (a refusal).

The two warnings (targets beyond the reach, far seeds) share their shape (``if far: rows =
listed(...); warnings.warn(f"{where}: {n} ...: row(s) {rows}; ...", MismatchWarning)``) and
are left as two blocks on purpose: they share no logic, only the frame of a sentence; a
helper would take each message in three pieces (what, the figures, the hint), push the
warning's stacklevel one frame down and save two lines a site, and the full message would
no longer be greppable where it is raised.
"""

from __future__ import annotations

import math
import warnings

import torch

from torchcal.calibration.checks.units import MISREAD, beyond_turn
from torchcal.calibration.checks.verdict import OUTLIER_SHARE, MismatchWarning, listed
from torchcal.errors import InputError

TARGET_RATIO = 20.0
REACH_MARGIN = 1.05
WORKSPACE_POSES = 2000
SEED_MM = 100.0  # a seed whose model point lies farther from its target is no nominal command of it


def workspace(model, theta: torch.Tensor, seed: int = 0):
    """(points (K, 3) mm, origin (3,) mm): the nominal geometry's TCP at WORKSPACE_POSES
    seeded random poses and the robot base origin, both mapped by the model's base frame.
    With a fitted tool offset each point is pushed away from the origin by the longest
    offset, the most the offset can add to its distance (else a target that the fitted
    tool reaches, e.g. a calibration pose with a 290 mm reflector, reads as out of reach)."""
    from torchcal.effects.base_frame import rotvec_to_matrix
    from torchcal.robots.poses import random_poses

    robot = model.robot
    q = random_poses(robot, WORKSPACE_POSES, torch.Generator().manual_seed(seed))
    with torch.no_grad():
        v = robot.fk(q.to(robot.device, robot.dtype)).detach().to("cpu", torch.float64)
    origin = robot.base[:3, 3].detach().to("cpu", torch.float64)
    for e, sl in zip(model.effects, model.slices[1:]):
        if e.name == "tool_offset":  # each point's offset turns with the flange: the farthest
            # point moves out by at most the longest offset (a reflector 290 mm off the flange)
            off = float(theta[sl].detach().to("cpu", torch.float64).reshape(-1, 3).norm(dim=-1).max())
            v = origin + (v - origin) * (1 + off / (v - origin).norm(dim=-1, keepdim=True).clamp_min(1e-9))
        if e.name == "base_frame":
            p = theta[sl].detach().to("cpu", torch.float64)
            R = rotvec_to_matrix(p[3:6])
            v, origin = v @ R.T + p[:3], R @ origin + p[:3]
    return v, origin


def _in_workspace(p: torch.Tensor, origin: torch.Tensor, reach: float) -> bool:
    """Points p (M, 3) mm whose median distance from the base origin lies within
    [reach / TARGET_RATIO, REACH_MARGIN * reach], at most OUTLIER_SHARE of them beyond it."""
    d = (p - origin).norm(dim=-1)
    return reach / TARGET_RATIO <= float(d.median()) <= REACH_MARGIN * reach and \
        float((d > REACH_MARGIN * reach).double().mean()) <= OUTLIER_SHARE


def _scaled_unit(t: torch.Tensor, origin: torch.Tensor, reach: float, about: torch.Tensor) -> str | None:
    """The `MISREAD` unit whose factor brings the targets t (M, 3) (numbers read as mm,
    scaled about `about` (3,), the origin of the frame they were given in, where a file's
    numbers are zero) into the workspace (`_in_workspace`); the first that does in
    `MISREAD`'s order (metres: numbers in metres times 25.4 can land in a large arm's
    workspace near the instrument; inches times 1000 lie 39 times too far), None when none."""
    for unit, (factor, _, _) in MISREAD.items():
        if _in_workspace(about + (t - about) * factor, origin, reach):
            return unit
    return None


def check_targets(model, theta: torch.Tensor, targets: torch.Tensor, where: str = "targets",
                  about: torch.Tensor | None = None, other_frame: tuple | None = None,
                  length_unit: str = "mm") -> list[int]:
    """Refuse targets (M, 3) mm that sit inside the robot's base or around the origin of
    their frame, and targets mostly beyond the reach, when a unit (`MISREAD`: metres,
    inches) or else the other frame would bring them into the workspace (one InputError
    naming it); warn (`MismatchWarning`) naming the other targets beyond the reach. about: (3,)
    mm, the origin of the frame the targets were given in, in the model's frame (None: the
    model's own, the measuring frame). other_frame: (points (M, 3) mm, the targets read in
    the other frame (robot base or measuring) mapped into the model's frame; its name;
    the `InputError.fix` that reads them so), or None. length_unit: the unit the targets
    were given in ('m': read times 1000; targets in mm given so lie 1000 times too far, and
    are refused when a thousandth of them lies in the workspace). Returns the 0-based rows
    beyond the reach."""
    pts, origin = workspace(model, theta)
    reach = float((pts - origin).norm(dim=-1).max())
    t = targets.detach().to("cpu", torch.float64)
    dist = (t - origin).norm(dim=-1)
    med = float(dist.median())
    med0 = float(t.norm(dim=-1).median())  # around the origin of the model's (measuring) frame
    far = (dist > REACH_MARGIN * reach).nonzero().flatten().tolist()
    wrong = med < reach / TARGET_RATIO or med0 < reach / TARGET_RATIO or len(far) > OUTLIER_SHARE * len(t)
    at = torch.zeros(3, dtype=torch.float64) if about is None else about.detach().to("cpu", torch.float64)
    if wrong and length_unit == "m" and _in_workspace(at + (t - at) / 1000.0, origin, reach):
        raise InputError(f"{where}: read in metres, the targets lie a median {med:.4g} mm from the base of "
                         f"{model.robot.name} (reach {reach:.4g} mm; {len(far)} of {len(t)} beyond it), and a "
                         "thousandth of them within its reach: they look like mm read as metres",
                         fix=("length_unit", "mm"))
    unit = _scaled_unit(t, origin, reach, at)
    if wrong and unit is None and other_frame is not None and \
            _in_workspace(other_frame[0].detach().to("cpu", torch.float64), origin, reach):
        raise InputError(f"{where}: as given the targets lie a median {med:.4g} mm from the base of "
                         f"{model.robot.name} (reach {reach:.4g} mm; {len(far)} of {len(t)} beyond it), but read in "
                         f"the {other_frame[1]} they would lie within its reach: they look like coordinates in the "
                         f"{other_frame[1]}", fix=other_frame[2])
    _, words, fix = MISREAD[unit] if unit is not None else (None, "wrong unit or wrong frame?", None)
    look = f"they look like {words}" if unit is not None else words
    if med0 < reach / TARGET_RATIO and med >= reach / TARGET_RATIO:
        raise InputError(f"{where}: the targets lie a median {med0:.4g} mm from the origin of the measuring frame, "
                         f"where no target of {model.robot.name} can be (its base is {float(origin.norm()):.4g} mm "
                         f"away): {look}", fix=fix)
    if med < reach / TARGET_RATIO:
        raise InputError(f"{where}: the targets lie a median {med:.4g} mm from the robot base, inside the base of "
                         f"{model.robot.name} (reach {reach:.4g} mm): {look}", fix=fix)
    if len(far) > OUTLIER_SHARE * len(t) and unit is not None:
        raise InputError(f"{where}: {len(far)} of {len(t)} targets lie beyond the reach of {model.robot.name} "
                         f"({reach:.4g} mm from its base; a median {med:.4g} mm), and x {MISREAD[unit][0]:g} they "
                         f"would lie within it: {look}", fix=fix)
    if far:
        rows = listed(i + 1 for i in far)
        warnings.warn(f"{where}: {len(far)} target(s) lie beyond the reach of {model.robot.name} ({reach:.4g} mm "
                      f"from the base; up to {float(dist.max()):.4g} mm): row(s) {rows}; another robot, "
                      "another frame (targets are in the model's frame) or units?", MismatchWarning, stacklevel=2)
    return far


def check_seeds(seed_points: torch.Tensor, targets: torch.Tensor, q0: torch.Tensor, robot,
                where: str = "targets", skip=(), angle_unit: str = "deg") -> list[int]:
    """Compensation seeds against their targets: a seed (the ``q1..qN`` of a targets file)
    is normally the nominal command of its target, where the model lies within the robot's
    absolute accuracy (a few mm) of it; the solve starts there and stays in its arm
    configuration.

    seed_points: (M, 3) mm, the model at the seeds q0 (M, n) rad / mm; targets (M, 3) mm in
    the same frame. InputError when every revolute seed lies within +-2 pi "degrees" and
    the median distance from seed point to target exceeds SEED_MM = 100 mm: radians in a
    degree column (the solve would converge from near-zero angles, in another arm
    configuration; fix angle_unit='rad'). A real set of seeds that only moves a few degrees
    sits on its targets and passes. Otherwise a `MismatchWarning` names the targets whose
    seed point lies beyond SEED_MM (the solution may lie in another arm configuration than
    the seed's); rows in `skip` (0-based: targets beyond the reach, named already) are not.
    angle_unit: the unit the seeds were given in: 'deg' (a targets file), or 'rad' (the
    library's q0), where seeds beyond what a joint can turn (`beyond_turn`) are degrees
    given as radians (an InputError naming `where`). Returns the named 0-based rows."""
    d = (seed_points.detach().to("cpu", torch.float64) - targets.detach().to("cpu", torch.float64)).norm(dim=-1)
    if d.numel() == 0:
        return []
    rev = ~robot.prismatic.cpu()
    q = q0.detach().to("cpu", torch.float64)[..., rev]
    med = float(d.median())
    bound = beyond_turn(q0, robot) if angle_unit == "rad" else None
    if bound is not None:
        raise InputError(f"{where}: seed angles reach {float(q.abs().max()):.4g} rad, beyond what a joint can turn "
                         f"({bound:.3g} rad): they look like degrees; seeds are in radians (torch.deg2rad)")
    if angle_unit == "deg" and q.numel() and math.degrees(float(q.abs().max())) <= 2 * math.pi + 1e-9 \
            and med > SEED_MM:
        raise InputError(f"{where}: every seed angle lies within +-{math.degrees(float(q.abs().max())):.4g} deg and "
                         f"the model at the seeds lies a median {med:.4g} mm from the targets: the seeds "
                         f"q1..q{robot.n} look like radians read as degrees", fix=("angle_unit", "rad"))
    far = [i for i in (d > SEED_MM).nonzero().flatten().tolist() if i not in set(skip)]
    if far:
        rows = listed(i + 1 for i in far)
        warnings.warn(f"{where}: {len(far)} seed(s) lie more than {SEED_MM:g} mm from their targets (the model at "
                      f"the seed; up to {float(d.max()):.4g} mm): row(s) {rows}; a seed is the target's nominal "
                      "command: the solution may lie in another arm configuration", MismatchWarning, stacklevel=2)
    return far


def check_target_conditions(model, targets: torch.Tensor, payload_kg=None, temp_c=None,
                            where: str = "targets") -> None:
    """InputError naming the effect of `model` that needs a condition (temp_c, payload_kg)
    the targets (M, 3) mm lack."""
    from torchcal.effects import make_context

    rob = model.robot
    probe = make_context(rob, rob.limits.mean(-1).expand(targets.shape[0], rob.n), payload_kg, temp_c)
    for e in model.effects:
        try:
            e.check_context(probe)
        except InputError as exc:
            if e.name == "tool_offset":  # one offset per reflector: which one is each target's?
                raise InputError(f"{where}: the model has one tool offset per reflector (points "
                                 f"{', '.join(map(str, e.points))}) and targets name no reflector; compensate "
                                 f"with a model fitted on the rows of one point") from None
            need = "column temp_c" if e.name == "thermal_expansion" else str(exc)
            raise InputError(f"{where}: the model's effect {e.spec()} needs {need} "
                             f"in the targets, which they lack") from None
