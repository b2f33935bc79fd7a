"""Which physical effect is the model missing? (DESIGN.md "Diagnosis")

1. Fit the current model (geometric + chosen effects) to all rows; residuals r (N, 3).
2. Where it fails: residual RMS per joint-angle quartile and per workspace region.
3. Each candidate (an effect of the vocabulary not in the model; joint effects one joint
   at a time) adds columns C (3N, k) = d model / d candidate parameters at the fit.
   Linearised around the fit, adding the candidate is the least-squares problem
   r ~ [J_free C] delta, with the geometric and effect columns J_free free to re-adapt.
   - Only what the model cannot already absorb counts: C is projected off span(J_free)
     and its numerical rank k (relative singular value > 1e-6) is the number of new
     parameters. k = 0 -> absorbed, never credited.
   - Cross-validated RMS: K folds by pose id (repeats of a pose stay together), the
     linear problem solved on the other folds, predicted on the held-out one.
   - Significance: nested-model F-test on all rows, ``F = ((RSS0 - RSS1) / k) /
     (RSS1 / (3N - p0 - k))``, with a Bonferroni-corrected level ``alpha / candidates``
     (alpha = 1e-3), *and* a cross-validated RMS gain of at least `min_gain` (2 %).
     Pure noise passes both with probability well under 1e-3.
4. Candidates are reported best first (lowest cross-validated RMS). The verdict is the
   best significant one; for a joint effect, a further joint of the same effect is added
   while, given the joints chosen so far, it is the best significant candidate of all
   (forward selection), so a hidden ``joint_compliance:2,3`` is named with both joints
   but a second, different effect is left to the next round of `discover`.

Everything is deterministic for a given seed (fold assignment).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.stats
import torch

from torchcal.effects import make_context
from torchcal.identify import FitResult, fit
from torchcal.io import Measurements
from torchcal.model import CalibrationModel
from torchcal.robot import Robot
from torchcal.spec import EFFECTS, parse_specs

ALPHA = 1e-3
MIN_GAIN = 0.02
RANK_TOL = 1e-6


@dataclass
class Candidate:
    effect: str
    joints: tuple
    rms_mm: float
    cv_rms_mm: float
    score: float
    p_value: float
    k: int
    significant: bool = False

    @property
    def spec(self) -> str:
        return self.effect if not self.joints else f"{self.effect}:{','.join(map(str, self.joints))}"

    def to_dict(self) -> dict:
        return {"effect": self.effect, "joints": list(self.joints), "rms_mm": self.rms_mm,
                "cv_rms_mm": self.cv_rms_mm, "score": self.score, "significant": self.significant,
                "p_value": self.p_value, "new_parameters": self.k}


@dataclass
class Diagnosis:
    baseline_effects: list
    baseline_fit: FitResult
    baseline_cv_rms_mm: float
    candidates: list
    verdict: Candidate | None
    where: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        res = self.baseline_fit.residuals.norm(dim=-1)
        return {
            "baseline": {"effects": list(self.baseline_effects), "rms_mm": self.baseline_fit.rms_mm,
                         "max_mm": float(res.max()), "cv_rms_mm": self.baseline_cv_rms_mm},
            "candidates": [c.to_dict() for c in self.candidates],
            "verdict": None if self.verdict is None else
            {"effect": self.verdict.effect, "joints": list(self.verdict.joints)},
            "where": self.where,
        }


def fold_ids(pose: torch.Tensor, folds: int, seed: int) -> np.ndarray:
    """(N,) fold of each row; all rows of one pose id share a fold."""
    ids, inverse = np.unique(pose.cpu().numpy(), return_inverse=True)
    rng = np.random.default_rng(seed)
    per_pose = rng.permutation(len(ids)) % folds
    return per_pose[inverse]


def _rms(r: np.ndarray) -> float:
    """Distance RMS (mm) of stacked residuals r (3M,)."""
    return float(np.sqrt((r.reshape(-1, 3) ** 2).sum(-1).mean()))


class _Linear:
    """The linearised refit around a fit: residual r (3N,), base columns A (3N, p0)."""

    def __init__(self, r: np.ndarray, A: np.ndarray, folds: np.ndarray):
        A = A / np.linalg.norm(A, axis=0).clip(1e-300)  # unit columns: rank cuts are relative
        self.r, self.A, self.rows = r, A, np.repeat(folds, 3)
        self.Q, _ = np.linalg.qr(A) if A.size else (np.zeros((len(r), 0)), None)
        self.folds = np.unique(folds)

    def new_columns(self, C: np.ndarray) -> np.ndarray:
        """An orthonormal basis (3N, k) of what C adds beyond span(A)."""
        Cp = C - self.Q @ (self.Q.T @ C)
        norms = np.linalg.norm(C, axis=0)
        Cp = Cp[:, norms > 0] / norms[norms > 0]
        if Cp.shape[1] == 0:
            return Cp
        U, s, _ = np.linalg.svd(Cp, full_matrices=False)
        return U[:, s > RANK_TOL]  # columns were normalised: s is relative

    def rss(self, B: np.ndarray) -> float:
        """Residual sum of squares of r on [A B] (B orthogonal to A and orthonormal)."""
        e = self.r - self.Q @ (self.Q.T @ self.r)
        return float(e @ e - ((B.T @ e) ** 2).sum()) if B.size else float(e @ e)

    def cv_rms(self, B: np.ndarray) -> float:
        """Cross-validated distance RMS of r on [A B]."""
        X = np.hstack([self.A, B]) if B.size else self.A
        out = np.empty_like(self.r)
        for f in self.folds:
            test = self.rows == f
            if X.shape[1]:
                coef, *_ = np.linalg.lstsq(X[~test], self.r[~test], rcond=1e-10)
                out[test] = self.r[test] - X[test] @ coef
            else:
                out[test] = self.r[test]
        return _rms(out)


def _candidate_specs(robot: Robot, present: dict, ctx) -> list[tuple[str, tuple]]:
    """Effects not in the model yet; joint effects on each joint they do not cover yet."""
    out = []
    for name, takes in EFFECTS.items():
        if name in present and not takes:
            continue
        if name == "thermal_expansion" and ctx.temp_c is None:
            continue
        if takes:
            out += [(name, (j,)) for j in range(1, robot.n + 1) if j not in present.get(name, ())]
        else:
            out.append((name, ()))
    return out


def _spec(name, joints):
    return name if not joints else f"{name}:{','.join(map(str, joints))}"


def candidate_columns(robot, base_model: CalibrationModel, theta, ctx, spec: str) -> np.ndarray:
    """d model / d candidate parameters at theta (3N, k), the candidate's values at zero."""
    aug = CalibrationModel(robot, base_model.specs() + [spec])
    k = aug.n_params - base_model.n_params

    def f(pc):
        return aug.predict(torch.cat([theta, pc]), ctx)

    C = torch.func.jacfwd(f)(torch.zeros(k, dtype=theta.dtype))
    return C.reshape(-1, k).detach().numpy()


def where_it_fails(robot: Robot, m: Measurements, residuals: torch.Tensor, bins: int = 4) -> dict:
    """Residual distance RMS per joint-angle quantile bin and per workspace region."""
    d = residuals.norm(dim=-1).numpy()
    q = torch.rad2deg(m.q).numpy()
    out = {"per_joint": [], "per_region": []}
    for j in range(robot.n):
        edges = np.quantile(q[:, j], np.linspace(0, 1, bins + 1))
        idx = np.clip(np.searchsorted(edges, q[:, j], side="right") - 1, 0, bins - 1)
        out["per_joint"].append({"joint": j + 1, "bins": [
            {"q_deg": [float(edges[b]), float(edges[b + 1])], "n": int((idx == b).sum()),
             "rms_mm": float(np.sqrt((d[idx == b] ** 2).mean())) if (idx == b).any() else None}
            for b in range(bins)]})
    xyz = m.xyz.numpy()
    reach = np.hypot(xyz[:, 0], xyz[:, 1])
    r_edges = np.quantile(reach, [0, 1 / 3, 2 / 3, 1])
    z_mid = float(np.median(xyz[:, 2]))
    for a in range(3):
        for upper in (False, True):
            sel = (reach >= r_edges[a]) & (reach <= r_edges[a + 1]) & ((xyz[:, 2] > z_mid) == upper)
            if sel.any():
                out["per_region"].append({
                    "reach_mm": [float(r_edges[a]), float(r_edges[a + 1])],
                    "z": "upper" if upper else "lower", "n": int(sel.sum()),
                    "rms_mm": float(np.sqrt((d[sel] ** 2).mean())), "max_mm": float(d[sel].max())})
    return out


def diagnose(robot: Robot, m: Measurements, effects=(), folds: int = 5, seed: int = 0,
             alpha: float = ALPHA, min_gain: float = MIN_GAIN, base_fit: FitResult | None = None) -> Diagnosis:
    """Rank the candidate effects missing from `robot` + `effects` on measurements m."""
    specs = [str(s) for s in parse_specs(list(effects), robot.n)] if effects else []
    model = CalibrationModel(robot, specs)
    ctx = make_context(robot, m.q, m.payload_kg, m.temp_c)
    if base_fit is None:
        base_fit = fit(model, ctx, m.xyz)
    theta = base_fit.theta
    r = base_fit.residuals.reshape(-1).numpy()
    A = model.jacobian(theta, ctx).reshape(-1, model.n_params)[:, base_fit.report.free].detach().numpy()
    lin = _Linear(r, A, fold_ids(m.pose, folds, seed))
    base_cv = lin.cv_rms(np.zeros((len(r), 0)))
    rss0, p0, n_eq = lin.rss(np.zeros((len(r), 0))), A.shape[1], len(r)
    present = {s.name: s.joints for s in parse_specs(specs, robot.n)} if specs else {}
    cands_specs = _candidate_specs(robot, present, ctx)
    level = alpha / max(len(cands_specs), 1)

    def judge(lin_, rss0_, p0_, base_cv_, name, joints, C):
        B = lin_.new_columns(C)
        k = B.shape[1]
        rss1 = lin_.rss(B)
        if k == 0:
            return Candidate(name, joints, _rms(lin_.r), base_cv_, 0.0, 1.0, 0)
        dof = max(n_eq - p0_ - k, 1)
        F = ((rss0_ - rss1) / k) / max(rss1 / dof, 1e-300)
        pval = float(scipy.stats.f.sf(F, k, dof))
        cv = lin_.cv_rms(B)
        score = (base_cv_ - cv) / max(base_cv_, 1e-300)
        c = Candidate(name, joints, float(np.sqrt(max(rss1, 0) / (n_eq / 3))), cv, float(score), pval, k)
        c.significant = bool(pval < level and score >= min_gain)
        return c

    columns = {}
    cands = []
    for name, joints in cands_specs:
        C = candidate_columns(robot, model, theta, ctx, _spec(name, joints))
        columns[(name, joints)] = C
        cands.append(judge(lin, rss0, p0, base_cv, name, joints, C))
    cands.sort(key=lambda c: (not c.significant, c.cv_rms_mm))
    verdict = next((c for c in cands if c.significant), None)
    if verdict is not None and verdict.joints:
        # forward selection of further joints of the same effect
        chosen = list(verdict.joints)
        C_in = columns[(verdict.effect, verdict.joints)]
        while True:
            A2 = np.hstack([lin.A, C_in])
            lin2 = _Linear(lin.r, A2, fold_ids(m.pose, folds, seed))
            rss0_2, cv0_2 = lin2.rss(np.zeros((n_eq, 0))), lin2.cv_rms(np.zeros((n_eq, 0)))
            best = None  # the best significant candidate of any effect, given the chosen
            for (name, joints), C in columns.items():
                if name == verdict.effect and joints[0] in chosen:
                    continue
                c = judge(lin2, rss0_2, A2.shape[1], cv0_2, name, joints, C)
                if c.significant and (best is None or c.cv_rms_mm < best.cv_rms_mm):
                    best = c
            if best is None or best.effect != verdict.effect:
                break  # another effect explains more: it is the next round's business
            chosen.append(best.joints[0])
            C_in = np.hstack([C_in, columns[(verdict.effect, best.joints)]])
        if len(chosen) > 1:
            verdict = Candidate(verdict.effect, tuple(sorted(chosen)), best_rms(lin, C_in),
                                lin.cv_rms(lin.new_columns(C_in)), verdict.score, verdict.p_value,
                                lin.new_columns(C_in).shape[1], True)
            cands.insert(0, verdict)
    where = where_it_fails(robot, m, base_fit.residuals)
    return Diagnosis(specs, base_fit, base_cv, cands, verdict, where)


def best_rms(lin: _Linear, C: np.ndarray) -> float:
    """Training distance RMS of the linear refit with columns C added."""
    return float(np.sqrt(max(lin.rss(lin.new_columns(C)), 0) / (len(lin.r) / 3)))


@dataclass
class Discovery:
    history: list
    final_effects: list
    fit: FitResult
    diagnoses: list

    def to_dict(self) -> dict:
        return {"history": self.history, "final_effects": self.final_effects}


def discover(robot: Robot, m: Measurements, effects=(), folds: int = 5, seed: int = 0,
             max_rounds: int = 6) -> Discovery:
    """Add the best significant effect each round until none is left.

    history[i] = {"effects", "rms_mm" (full nonlinear refit, training), "cv_rms_mm"}.
    """
    specs = [str(s) for s in parse_specs(list(effects), robot.n)] if effects else []
    history, diagnoses = [], []
    ctx = make_context(robot, m.q, m.payload_kg, m.temp_c)
    base = fit(CalibrationModel(robot, specs), ctx, m.xyz)
    for _ in range(max_rounds + 1):
        d = diagnose(robot, m, specs, folds=folds, seed=seed, base_fit=base)
        diagnoses.append(d)
        history.append({"effects": list(specs), "rms_mm": base.rms_mm, "cv_rms_mm": d.baseline_cv_rms_mm})
        if d.verdict is None or len(history) > max_rounds:
            break
        specs = [str(s) for s in parse_specs(specs + [d.verdict.spec], robot.n)]
        base = fit(CalibrationModel(robot, specs), ctx, m.xyz)
    return Discovery(history, specs, base, diagnoses)
