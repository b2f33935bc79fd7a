"""Physics or absorption: does an effect's gain hold where it was not fitted?

A physical effect predicts: fitted on one part of the workspace, it lowers the error on
another. An effect that only absorbs structure it does not model (a clearance soaking up
part of a hose force) takes whatever values fit that structure where it is fitted; it
gains on held-out poses drawn from the same region (the refit CV of a step), yet
carried to a part of the workspace it has not seen it gains nothing, or loses.

The test, for an effect e of a fitted model (`FitResult` ``full``): for each joint angle
q_j that varies, the poses are split at the median of q_j into two halves (a pose's rows
together). The model is refitted on one half and predicts the other, both ways (a
two-fold refit CV whose folds are the halves, `extrapolated`: fold refits of
`torchcal.diagnosis.crossval.fold_refits`, from the shared Jacobian of
`torchcal.calibration.refit` where it applies), with e and without it (the model without
e fitted on all rows first, from ``full``). A split is used only where
each half determines what the full data determine (every parameter whose posterior sd
is below half its plausible size on all rows stays so on each half, the rule of
`torchcal.calibration.plausibility.determination`): fitted on half of a joint's range,
the harmonics of that joint's gear error are not determined, and predicting the other
half from them tests that, not the physics. Per pose p,
``d_p = e_without_p - e_with_p``, the extrapolated squared distance error without e
minus with e; a one-sided paired t-test over the poses of mean(d) > 0
(`torchcal.diagnosis.selection.paired_p_value`). e is physics when its extrapolated gain
is beyond chance in every split: p < ALPHA in each (an intersection-union test: its
level is ALPHA without a correction over the splits); ALPHA 0.01, the level of the
probe's test, chosen before any session was looked at. Otherwise it is taken for an
absorber, and the split where its gain failed is named.

Why not a test of the parameters themselves (a Chow / Wald test of the parameters
fitted on the two halves): it rejects true effects whenever anything else is missing or
the gauge of the halves differs (on the simulated session of tests/test_discover.py,
the true gear_periodic:2 and joint_compliance:3 of the final model gave p 0 and 4e-4),
and it accepts an absorber whose parameters the data barely determine (joint_clearance:1
in hose sessions), so it named the absorber and not the physics (docs/diagnosis.md).

An effect on several joints (``joint_periodic:1@12+22,2@20+29``, ``gear_periodic:1,2,3``)
is one effect of the model but a separate claim per joint: one joint's gear error can be
physics while another joint's terms absorb something else. Its test is made per joint
(`part_specs`): joint j's part is tested as above, the model with all of the effect
against the model with the effect on the other joints only (same splits, same rule, same
ALPHA; the 'with' side is the same fit for every part). The joints whose part holds are
named, the others are fit terms; the whole effect has no test of its own (the rule was
fixed before the UR10 outcome was looked at; docs/diagnosis.md).

`discover` applies it to the effects it added, in its final model (`absorbing`): an
effect (or an effect's joint part) that fails stays in the model as a fit term (the
held-out error it bought is real) and is reported as absorbing, not named as physics.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.plausibility import determination
from torchcal.calibration.refit import warm_fit
from torchcal.diagnosis.crossval import held_out_errors, lm_only, per_pose
from torchcal.diagnosis.selection import paired_p_value
from torchcal.effects.spec import format_spec, parse_spec
from torchcal.errors import InputError

#: level of the extrapolated gain's test in each split.
ALPHA = 0.01


@dataclass
class Stability:
    """Result of `stability` for one effect: p_value, the largest over the splits (the
    intersection-union test's p-value); split: the variable of that split ('q3'); gain:
    the extrapolated distance-RMS gain there (mm, without minus with); splits: how many
    were tested; level: ALPHA. stable: p_value < level (True when nothing was tested).

    parts: for an effect on several joints, joint (1-based) -> (the spec of that joint's
    part, its own `Stability`); the effect's own fields then repeat those of its worst
    part (largest p-value); stable: every part stable. `split_spec` says what is named
    and what is a fit term."""

    p_value: float
    split: str
    gain_mm: float
    splits: int
    level: float = ALPHA
    parts: dict = field(default_factory=dict)

    @property
    def stable(self) -> bool:
        if self.parts:
            return all(st.stable for _, st in self.parts.values())
        return self.splits == 0 or self.p_value < self.level

    def split_spec(self, spec: str) -> tuple[list, list]:
        """([specs named as physics], [(spec, Stability) kept as fit terms]) of the effect
        `spec` tested here: the whole spec on one side, or per joint part."""
        if not self.parts:
            return ([spec], []) if self.stable else ([], [(spec, self)])
        named = [j for j, (_, st) in self.parts.items() if st.stable]
        return (([restricted(spec, named, max(self.parts))] if named else []),
                [(part, st) for j, (part, st) in self.parts.items() if j not in named])

    def words(self) -> str:
        """Why an effect is taken for an absorber, in words."""
        return (f"fitted on the poses on one side of the median of {self.split} it does not predict the other side "
                f"better (extrapolated gain {1000 * self.gain_mm:+.1f} um, p {self.p_value:.2g} >= {self.level:g})")

    def to_dict(self) -> dict:
        out = {"stable": self.stable, "p_value": self.p_value, "split": self.split, "gain_mm": self.gain_mm,
               "splits": self.splits, "level": self.level}
        if self.parts:
            out["parts"] = {str(j): {"spec": part, **st.to_dict()} for j, (part, st) in self.parts.items()}
        return out


def part_specs(spec: str, n_joints: int) -> dict:
    """joint (1-based) -> (the spec of that joint's part, the spec of the effect without
    it) for an effect on several joints (``joint_periodic:1@12,2@20+29`` -> {1:
    ('joint_periodic:1@12', 'joint_periodic:2@20+29'), 2: (...)}); {} for an effect on
    one joint or none."""
    joints = parse_spec(spec, n_joints).joints
    if len(joints) < 2:
        return {}
    return {j: (restricted(spec, [j], n_joints), restricted(spec, [k for k in joints if k != j], n_joints))
            for j in joints}


def restricted(spec: str, joints, n_joints: int) -> str:
    """The effect `spec` on the `joints` (1-based) among its own only, each with its orders
    (``joint_periodic:1@12,2@20+29,3@18`` on [1, 3] -> ``joint_periodic:1@12,3@18``)."""
    s = parse_spec(spec, n_joints)
    keep = [i for i, j in enumerate(s.joints) if j in set(joints)]
    return format_spec(s.name, [s.joints[i] for i in keep], [s.orders[i] for i in keep] if s.orders else ())


def halves(m) -> dict:
    """'qJ' -> (N,) int 0/1: the halves of the poses below and above the median of each
    joint angle that varies (a pose's rows on one side)."""
    pose = m.pose.cpu().numpy()
    q = m.q.detach().cpu().numpy()
    _, first, inv = np.unique(pose, return_index=True, return_inverse=True)
    out = {}
    for j in range(q.shape[1]):
        qp = q[first, j]
        if np.ptp(qp) > 0:
            out[f"q{j + 1}"] = (qp > np.median(qp)).astype(np.int64)[inv]
    return out


def without(full, spec: str, m, ctx, *, sigma_mm: float, sigma_deg: float, by: str | None = None):
    """The model of `full` (`FitResult`) without the effect `spec` (replaced by the spec
    `by` when given: the effect on fewer joints), fitted on all of m from full's values,
    with full's held parameters held."""
    from torchcal.diagnosis.step import fit_options

    specs = [s for s in full.model.specs() if s != spec] if by is None else \
        [by if s == spec else s for s in full.model.specs()]
    model = CalibrationModel.for_measurements(full.model.robot, specs, m)
    names, held = full.model.param_names(), set(full.report.held)
    theta0, free = model.zeros(), model.default_free()
    for i, n in enumerate(model.param_names()):
        if n in names:
            theta0[i] = full.theta[names.index(n)]
        free[i] &= n not in held
    res = None if lm_only(full) else warm_fit(model, ctx, m.xyz, theta0, free,
                                              **fit_options(m, sigma_mm=sigma_mm, sigma_deg=sigma_deg))
    return res if res is not None else \
        fit(model, ctx, m.xyz, theta0=theta0, free=free, **fit_options(m, sigma_mm=sigma_mm, sigma_deg=sigma_deg))


def determined_names(full, ctx) -> list:
    """The parameters of the fitted model `full` its data determine (`determination`'s rule:
    posterior sd below half the plausible size, or no plausible size), context ctx."""
    names = full.model.param_names()
    return [n for n in names if n not in {d["name"] for d in determination(full, names, ctx, partners=False)}]


def extrapolated(full, m, ctx, half: np.ndarray, *, sigma_mm: float, sigma_deg: float, determined=None):
    """(per-pose squared errors (P,) mm^2, distance RMS mm) of the model `full` refitted
    on each half of `half` (N,) 0/1 and predicting the other; None when a half cannot
    carry it, or when a parameter the full fit determines is not determined on a half
    (posterior sd at least half its plausible size, `determination`'s rule: the split
    then tests what the half cannot resolve, e.g. the harmonics of a joint over half its
    range, not the physics). determined: `determined_names` of full (computed here when None)."""
    determined = determined_names(full, ctx) if determined is None else determined
    try:
        err = held_out_errors(full, m, ctx, half, sigma_mm=sigma_mm, sigma_deg=sigma_deg,
                              accept=lambda res: all(d["why"] != "prior"
                                                     for d in determination(res, determined, ctx, partners=False)))
    except InputError:
        return None
    return None if err is None else (per_pose(m, err), float(np.sqrt(err.mean())))


def _tested(reduced, with_e: dict, m, ctx, *, sigma_mm: float, sigma_deg: float, alpha: float) -> Stability:
    """The test of `reduced` (the model without the effect or part, or None when it cannot
    be fitted) against the 'with' side `with_e` (split name -> `extrapolated` of the full
    model, usable splits only)."""
    results = []
    det_reduced = None  # the same in every split: computed once, when first needed
    for name, (half, with_) in with_e.items():
        if reduced is not None and det_reduced is None:
            det_reduced = determined_names(reduced, ctx)
        without_e = None if reduced is None else extrapolated(reduced, m, ctx, half, sigma_mm=sigma_mm,
                                                              sigma_deg=sigma_deg, determined=det_reduced)
        if without_e is not None:
            results.append((paired_p_value(without_e[0], with_[0]), name, without_e[1] - with_[1]))
    if not results:
        return Stability(1.0, "", 0.0, 0, alpha)
    p, name, gain = max(results)
    return Stability(p, name, gain, len(results), alpha)


def with_side(full, m, ctx, *, sigma_mm: float, sigma_deg: float) -> dict:
    """The 'with' side of the test: split name -> (half (N,) 0/1, `extrapolated` of the
    full model `full`), the usable splits of `halves(m)` only. It depends on full alone,
    not on the effect tested: `absorbing` computes it once for all its effects."""
    det_full = determined_names(full, ctx)  # the same in every split
    out = {}
    for name, half in halves(m).items():
        w = extrapolated(full, m, ctx, half, sigma_mm=sigma_mm, sigma_deg=sigma_deg, determined=det_full)
        if w is not None:
            out[name] = (half, w)
    return out


def stability(full, spec: str, m, ctx, *, sigma_mm: float, sigma_deg: float, alpha: float = ALPHA,
              with_e=None) -> Stability:
    """The extrapolation test of the effect `spec` of the fitted model `full` on
    measurements m (context ctx), per joint part for an effect on several joints; see
    the module doc. with_e: a callable giving `with_side` of full (computed here when
    None; `absorbing` passes one that computes it once)."""
    parts = part_specs(spec, full.model.robot.n)
    reduced = {}
    for j, by in ({None: None} if not parts else {j: rest for j, (_, rest) in parts.items()}).items():
        try:
            reduced[j] = without(full, spec, m, ctx, sigma_mm=sigma_mm, sigma_deg=sigma_deg, by=by)
        except InputError:
            reduced[j] = None
    side = {}
    if any(r is not None for r in reduced.values()):
        side = with_side(full, m, ctx, sigma_mm=sigma_mm, sigma_deg=sigma_deg) if with_e is None else with_e()
    kw = dict(sigma_mm=sigma_mm, sigma_deg=sigma_deg, alpha=alpha)
    if not parts:
        return _tested(reduced[None], side, m, ctx, **kw)
    tests = {j: (parts[j][0], _tested(reduced[j], side, m, ctx, **kw)) for j in parts}
    worst = max((st for _, st in tests.values()), key=lambda st: (st.splits > 0, st.p_value))
    return Stability(worst.p_value, worst.split, worst.gain_mm, worst.splits, alpha, parts=tests)


def absorbing(full, added: list, m, ctx, *, sigma_mm: float, sigma_deg: float, alpha: float = ALPHA) -> dict:
    """spec -> `Stability` of each effect spec in `added` in the fitted model `full` (per
    joint part for an effect on several joints). The full model's side of the test
    (`with_side`) is the same for every effect: computed once, when first needed."""
    side = functools.cache(lambda: with_side(full, m, ctx, sigma_mm=sigma_mm, sigma_deg=sigma_deg))
    return {spec: stability(full, spec, m, ctx, sigma_mm=sigma_mm, sigma_deg=sigma_deg, alpha=alpha, with_e=side)
            for spec in added}
