"""The pre-screen: every candidate scored by a linearised refit around the current fit.

Each candidate (an effect of the vocabulary not in the model; joint effects one joint at
a time) adds columns C (3N, k) = d model / d candidate parameters at the fit. Linearised
around the fit, adding the candidate is the least-squares problem r ~ [J_free C] delta,
with the geometric and effect columns J_free free to re-adapt (positions only: it ranks,
the full refit of torchcal.diagnosis.step decides, with orientation when measured).

- Only what the model cannot already absorb counts: C is projected off span(J_free) and
  its numerical rank k (relative singular value > 1e-6) is the number of new parameters.
  k = 0 -> absorbed, never credited.
- Cross-validated: K folds by pose id, the linear problem solved on the other folds and
  predicted on the held-out one; the held-out RMS and the held-out Gaussian
  log-likelihood (variance fitted on the other folds).
- Significance: nested-model F-test on pose means, ``F = ((RSS0 - RSS1) / k) /
  (RSS1 / (3P - p0 - k))``, at a Bonferroni-corrected level ``alpha / 2 / candidates``,
  *and* a held-out RMS gain of at least `min_gain` (2 %).
- `joint_clearance` also has a random part per move that no deterministic term can
  predict. Its candidate adds a variance term: residual covariance
  ``sigma^2 I + tau_J^2 B_J B_J^T`` with B_J (3, 2) the TCP motion per random tilt of
  joint J's axis about the two directions perpendicular to it. It is significant when its
  deterministic part is, or when a likelihood-ratio test of tau_J (boundary mixture
  0.5 chi2) passes the same level and the held-out log-likelihood gains at least
  `MIN_LL_GAIN` nats per pose.
- Candidates are ranked and a verdict proposed by `torchcal.diagnosis.selection`; for a
  joint effect, a further joint of the same effect is added while, given the joints
  chosen so far, it is the best significant candidate of all (forward selection, at
  alpha / 2^(s+1) for step s), so a hidden ``joint_compliance:2,3`` is proposed with both
  joints but a second, different effect is left to the next round of `discover`.
- `joint_periodic` (orders per joint) is a candidate on joint J with the orders that
  `torchcal.diagnosis.spectral.propose_orders` finds in the residual on the same folds;
  a joint where it finds none is no candidate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from torchcal.diagnosis.candidates import Candidate, all_candidate_columns, candidate_specs, random_clearance_basis
from torchcal.diagnosis.crossval import LinearRefit
from torchcal.diagnosis.selection import MIN_LL_GAIN, rank, select
from torchcal.diagnosis.spectral import propose_orders, search_base
from torchcal.diagnosis.variance import fit_variance, variance_loglik
from torchcal.effects.spec import parse_specs
from torchcal.statistics import chi2_sf, f_sf


@dataclass
class Screen:
    """The pre-screen's result: candidates (ranked, the forward-selected verdict first
    when it has several joints), verdict (the proposed candidate or None), cv_rms_mm (the
    linearised held-out RMS of the current model)."""

    candidates: list
    verdict: Candidate | None
    cv_rms_mm: float


def prescreen(robot, model, specs: list, base_fit, m, ctx, folds_: np.ndarray, *, alpha: float,
              min_gain: float) -> Screen:
    """Score every candidate missing from `model` (fitted: base_fit) on measurements m
    (context ctx) with the folds folds_ (N,) (module doc)."""
    theta = base_fit.theta
    r = base_fit.residuals.reshape(-1).numpy(force=True)
    A = model.jacobian(theta, ctx).reshape(-1, model.n_params)[:, base_fit.report.free].numpy(force=True)
    pose_np = m.pose.cpu().numpy()
    lin = LinearRefit(r, A, folds_, pose_np)
    n_eq = len(r)
    present = {s.name: s.joints for s in parse_specs(specs, robot.n)} if specs else {}
    cands_specs = candidate_specs(robot, present, ctx)
    searched = [j for n, j in cands_specs if n == "joint_periodic"]
    base = search_base(r, A, folds_) if searched else None  # every joint's search shares its QRs
    orders = {("joint_periodic", j): (propose_orders(robot, model, theta, ctx, r, A, folds_, j[0], base=base).orders,)
              for j in searched}
    orders = {key: ks for key, ks in orders.items() if ks[0]}
    cands_specs = [(n, j) for n, j in cands_specs if n != "joint_periodic" or (n, j) in orders]
    # alpha spending: this call's first family gets alpha / 2, forward-selection step s
    # alpha / 2^(s+1), each split evenly (Bonferroni) over the candidates it tests
    level = alpha / 2 / max(len(cands_specs), 1)

    def judge(name, joints, lin_, Bs_in, C, Bs, base_cv, base_ll, level):
        """Evidence for adding (C, Bs) to the linear base lin_ with variance terms Bs_in;
        the tests run on pose means (see the module doc), at `level`."""
        B = lin_.new_columns(C)
        k = B.shape[1]
        e1 = lin_.residual(B)
        rss1 = float(e1 @ e1)
        if lin_.rows_are_poses:  # the pose-level problem is the row-level one: the same numbers
            Bb, e0b, e1b = B, lin_.residual(np.zeros((len(lin_.r), 0))), e1
        else:
            Bb = lin_.pose_columns(C)
            e0b, e1b = lin_.pose_residual(np.zeros((len(lin_.rb), 0))), lin_.pose_residual(Bb)
        kb = Bb.shape[1]
        rss0b, rss1b = float(e0b @ e0b), float(e1b @ e1b)
        p_f = 1.0
        if k and kb:
            dof = max(len(lin_.rb) - lin_.Qb.shape[1] - kb, 1)
            F = ((rss0b - rss1b) / kb) / max(rss1b / dof, 1e-300)
            p_f = f_sf(F, kb, dof)
        Bs_all = Bs_in if Bs is None else (Bs if Bs_in is None else np.concatenate([Bs_in, Bs], -1))
        cv, ll = lin_.cross_validate(B, Bs_all)
        ll_rows, sq_rows = lin_.last_ll, lin_.last_sq
        gain = (base_cv - cv) / max(base_cv, 1e-300)
        score = ll - base_ll
        significant = deterministic = k > 0 and p_f < level and gain >= min_gain
        p_lr = 1.0
        if Bs is not None:  # likelihood-ratio test of the random part, on pose means
            e3 = e1b.reshape(-1, 3)
            ll0 = variance_loglik(e3, pose_basis(Bs_in), fit_variance(e3, pose_basis(Bs_in))).sum()
            ll1 = variance_loglik(e3, pose_basis(Bs_all), fit_variance(e3, pose_basis(Bs_all))).sum()
            p_lr = 0.5 * chi2_sf(max(2 * (ll1 - ll0), 0.0), Bs.shape[-1] // 2)
            significant = significant or (p_lr < level and score >= MIN_LL_GAIN)
        return Candidate(name, joints, float(np.sqrt(max(rss1, 0) / (n_eq / 3))), cv, float(score),
                         min(p_f, p_lr), k + (0 if Bs is None else Bs.shape[-1] // 2),
                         bool(significant), float(gain), ll_rows, sq_rows, bool(deterministic))

    def pose_basis(Bs):
        """Random-tilt basis of pose means: the mean of m independent tilts of one pose
        has covariance tau^2 B B^T / m (repeats of a pose share q, hence B)."""
        if Bs is None:
            return None
        N, _, K = Bs.shape
        out = lin.pose_mean(Bs.reshape(N * 3, K)).reshape(-1, 3, K)
        return out / np.sqrt(lin.counts)[:, None, None]

    columns, variance = all_candidate_columns(robot, model, theta, ctx, cands_specs, orders), {}
    for name, joints in cands_specs:
        if name == "joint_clearance":
            variance[(name, joints)] = random_clearance_basis(robot, ctx, m.xyz, joints[0])
    base_cv, base_ll = lin.cross_validate(np.zeros((n_eq, 0)), None)
    cands = [judge(n, j, lin, None, C, variance.get((n, j)), base_cv, base_ll, level)
             for (n, j), C in columns.items()]
    for c in cands:
        c.orders = orders.get((c.effect, c.joints), ())
    cands = rank(cands)
    verdict = select(cands)
    if verdict is not None and verdict.joints:
        # forward selection: add a joint of the same effect while, given the joints chosen
        # so far, it is the best significant candidate of all
        chosen = list(verdict.joints)
        step_alpha = alpha / 2
        while True:
            step_alpha /= 2
            C_in = np.hstack([columns[(verdict.effect, (j,))] for j in chosen])
            Bs_in = None if verdict.effect != "joint_clearance" else \
                np.concatenate([variance[(verdict.effect, (j,))] for j in chosen], -1)
            lin_in = LinearRefit(r, np.hstack([A, C_in]), folds_, pose_np)
            cv_in, ll_in = lin_in.cross_validate(np.zeros((n_eq, 0)), Bs_in)
            # other effects' random parts are the next round's business: not refitted here
            step = [judge(n, j, lin_in, Bs_in, C, variance.get((n, j)) if n == verdict.effect else None,
                          cv_in, ll_in, step_alpha / max(len(columns) - len(chosen), 1))
                    for (n, j), C in columns.items() if not (n == verdict.effect and j[0] in chosen)]
            best = select(rank(step))
            if best is None or best.effect != verdict.effect:
                break  # another effect explains more: it is the next round's business
            chosen.append(best.joints[0])
        if len(chosen) > 1:
            C_all = np.hstack([columns[(verdict.effect, (j,))] for j in chosen])
            Bs_all = None if verdict.effect != "joint_clearance" else \
                np.concatenate([variance[(verdict.effect, (j,))] for j in chosen], -1)
            B = lin.new_columns(C_all)
            cv, ll = lin.cross_validate(B, Bs_all)
            e = lin.residual(B)
            verdict = Candidate(verdict.effect, tuple(sorted(chosen)), float(np.sqrt(e @ e / (n_eq / 3))),
                                cv, ll - base_ll, verdict.p_value, B.shape[1], True,
                                (base_cv - cv) / max(base_cv, 1e-300), deterministic=verdict.deterministic,
                                orders=tuple(orders[(verdict.effect, (j,))][0] for j in sorted(chosen))
                                if verdict.orders else ())
            cands.insert(0, verdict)
    return Screen(cands, verdict, base_cv)
