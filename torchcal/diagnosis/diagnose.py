"""Which physical effect is the model missing? (docs/design.md "Diagnosis")

1. Fit the current model (geometric + chosen effects) to all rows; residuals r (N, 3).
2. Where it fails: residual RMS per joint-angle quartile and per workspace region.
3. Each candidate (an effect of the vocabulary not in the model; joint effects one joint
   at a time) adds columns C (3N, k) = d model / d candidate parameters at the fit.
   Linearised around the fit, adding the candidate is the least-squares problem
   r ~ [J_free C] delta, with the geometric and effect columns J_free free to re-adapt.
   - Only what the model cannot already absorb counts: C is projected off span(J_free)
     and its numerical rank k (relative singular value > 1e-6) is the number of new
     parameters. k = 0 -> absorbed, never credited.
   - Cross-validated: K folds by pose id (repeats of a pose stay together), the linear
     problem solved on the other folds and predicted on the held-out one; the held-out
     RMS and the held-out Gaussian log-likelihood (variance fitted on the other folds).
   - Significance: nested-model F-test on all rows, ``F = ((RSS0 - RSS1) / k) /
     (RSS1 / (3N - p0 - k))``, with a Bonferroni-corrected level ``alpha / candidates``
     (alpha = 1e-3), *and* a held-out RMS gain of at least `min_gain` (2 %).
   - `joint_clearance` also has a random part per move that no deterministic term can
     predict. Its candidate adds a variance term: residual covariance
     ``sigma^2 I + tau_J^2 B_J B_J^T`` with B_J (3, 2) the TCP motion per random tilt of
     joint J's axis about the two directions perpendicular to it. It is significant when
     its deterministic part is, or when a likelihood-ratio test of tau_J (boundary
     mixture 0.5 chi2) passes the same level and the held-out log-likelihood gains at
     least `MIN_LL_GAIN` nats per pose.
4. Candidates are reported best first: significant by a deterministic part (by held-out
   RMS), then significant by a random part only (by `score`, the held-out
   log-likelihood gain per pose), then the rest. The verdict is the best of the first
   tier, or of the second when the first is empty (a variance term can soak up structure
   a deterministic effect predicts, so a prediction is preferred); within the tier, a
   simpler candidate (fewer new parameters) that the best does not beat significantly
   per pose (paired held-out errors, two standard errors) is preferred; for a joint effect, a further joint of the same effect is added
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

from torchcal.effects import build, context_of
from torchcal.calibration.fit import FitResult, fit
from torchcal.measurements import Measurements
from torchcal.calibration.model import CalibrationModel
from torchcal.robots.robot import Robot
from torchcal.effects.spec import EFFECTS, parse_specs
from torchcal.diagnosis.unexplained import Unexplained, unexplained

ALPHA = 1e-3
MIN_GAIN = 0.02
MIN_LL_GAIN = 0.15  # nats per pose, for a variance (random clearance) term: the Gaussian
# model of a disc-shaped random tilt is misspecified, which alone is worth ~0.06
RANK_TOL = 1e-6
MRAD = 1e-3  # random-clearance tilts are fitted in mrad


@dataclass
class Candidate:
    """One candidate effect and its evidence.

    rms_mm: training distance RMS of the linearised refit with it; cv_rms_mm: held-out;
    cv_gain: relative held-out RMS gain; score: held-out log-likelihood gain, nats per
    pose (the ranking); p_value: F-test (deterministic part) or likelihood-ratio test
    (random part), whichever is smaller; k: new identifiable parameters; held_out_ll,
    held_out_sq: per-pose held-out log-likelihood and squared distance error;
    deterministic: significant by its deterministic part (else, if significant, by its
    random part only).
    """

    effect: str
    joints: tuple
    rms_mm: float
    cv_rms_mm: float
    score: float
    p_value: float
    k: int
    significant: bool = False
    cv_gain: float = 0.0
    held_out_ll: np.ndarray | None = field(default=None, repr=False)  # (poses,) nats
    held_out_sq: np.ndarray | None = field(default=None, repr=False)  # (poses,) mm^2
    deterministic: bool = False  # significant by its deterministic part (F-test + gain)

    @property
    def spec(self) -> str:
        return self.effect if not self.joints else f"{self.effect}:{','.join(map(str, self.joints))}"

    def to_dict(self) -> dict:
        return {"effect": self.effect, "joints": list(self.joints), "rms_mm": self.rms_mm,
                "cv_rms_mm": self.cv_rms_mm, "score": self.score, "significant": self.significant,
                "p_value": self.p_value, "new_parameters": self.k, "cv_gain": self.cv_gain}


@dataclass
class Diagnosis:
    baseline_effects: list
    baseline_fit: FitResult
    baseline_cv_rms_mm: float
    candidates: list
    verdict: Candidate | None
    where: dict = field(default_factory=dict)
    unexplained: Unexplained | None = None  # what remains after the baseline + the verdict

    def to_dict(self) -> dict:
        res = self.baseline_fit.residuals.norm(dim=-1)
        return {
            "baseline": {"effects": list(self.baseline_effects), "rms_mm": self.baseline_fit.rms_mm,
                         "max_mm": float(res.max()), "cv_rms_mm": self.baseline_cv_rms_mm},
            "candidates": [c.to_dict() for c in self.candidates],
            "verdict": None if self.verdict is None else
            {"effect": self.verdict.effect, "joints": list(self.verdict.joints)},
            "where": self.where,
            "unexplained": None if self.unexplained is None else self.unexplained.to_dict(),
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


# -- the random part: residual covariance sigma^2 I + sum_j tau_j^2 B_j B_j^T ------------

def _variance_loglik(r3: np.ndarray, Bs: np.ndarray | None, logp: np.ndarray) -> np.ndarray:
    """Per-row Gaussian log-likelihood (M,) of residuals r3 (M, 3).

    Bs (M, 3, K): TCP displacement per mrad of random tilt; logp = [log sigma^2,
    log tau_1^2, ...]. Bs None: isotropic sigma^2 only.
    """
    S = np.exp(logp[0]) * np.eye(3)[None].repeat(len(r3), 0)
    if Bs is not None and Bs.shape[-1]:
        tau = np.exp(logp[1:]).repeat(Bs.shape[-1] // (len(logp) - 1))
        S = S + np.einsum("mik,k,mjk->mij", Bs, tau, Bs)
    sign, logdet = np.linalg.slogdet(S)
    quad = np.einsum("mi,mi->m", r3, np.linalg.solve(S, r3[..., None])[..., 0])
    return -0.5 * (logdet + quad + 3 * np.log(2 * np.pi))


def _mm(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Batched small matrix product a @ b by broadcasting (CPU matmul loops over tiny batches)."""
    return (a.unsqueeze(-1) * b.unsqueeze(-3)).sum(-2)


def _mv(a: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Batched small matrix-vector product a @ v, a (..., i, j), v (..., j)."""
    return (a * v.unsqueeze(-2)).sum(-1)


def _inv3(S: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Inverse (..., 3, 3) and determinant (...) of symmetric 3 x 3 matrices, closed form."""
    a, b, c = S[..., 0, 0], S[..., 0, 1], S[..., 0, 2]
    d, e, f = S[..., 1, 1], S[..., 1, 2], S[..., 2, 2]
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * A + b * B + c * C
    adj = torch.stack([A, B, C, B, a * f - c * c, b * c - a * e, C, b * c - a * e, a * d - b * b], -1)
    return (adj / det.unsqueeze(-1)).reshape(S.shape), det


def _variance_start(r3: torch.Tensor, Bs: torch.Tensor | None, w: torch.Tensor, K: int):
    """Start and bounds (G, 1 + K) of the log variances: log sigma^2 at the log mean
    square, within [-9, +5] of it; each log tau^2 where its rows' mean |B|_F^2 tau^2
    equals that mean square, within [-30, +10] of it."""
    n = w.sum(-1).clamp_min(1.0)
    ls2 = torch.log((((r3 ** 2).mean(-1) * w).sum(-1) / n).clamp_min(1e-300))  # (G,)
    if not K:
        return ls2[:, None], None, None
    bb = ((Bs ** 2).sum((-2, -1)) * w).sum(-1) / n  # (G,)
    lt = ls2 - 2 * torch.log(bb.sqrt().clamp_min(1e-12))
    x0 = torch.cat([ls2[:, None], lt[:, None].expand(-1, K)], -1)
    lo = torch.cat([(ls2 - 9)[:, None], (lt - 30)[:, None].expand(-1, K)], -1)
    hi = torch.cat([(ls2 + 5)[:, None], (lt + 10)[:, None].expand(-1, K)], -1)
    return x0, lo, hi


def fit_variances(r3: torch.Tensor, Bs: torch.Tensor | None, w: torch.Tensor | None = None,
                  iters: int = 100, tol: float = 1e-10) -> torch.Tensor:
    """Maximum-likelihood log variances (G, 1 + K) of G sets of residual rows at once.

    r3 (G, M, 3) mm; Bs (M, 3, 2K) or (G, M, 3, 2K), mm per mrad (None or no columns:
    isotropic only); w (G, M) row weights (1: the row counts, 0: it does not; default
    all 1). Row m has covariance ``S_m = exp(x_0) I + sum_j exp(x_j) B_j B_j^T``, B_j its
    j-th pair of columns. Isotropic: the closed form (log mean square). Else a projected
    Newton method on x within the bounds of `_variance_start`, with the analytic gradient
    and Hessian of ``0.5 sum_m w_m (log det S_m + r_m^T S_m^-1 r_m)`` (the expected,
    Fisher, Hessian where the exact one is not positive definite), a backtracking line
    search, and, for a tau^2 whose maximum is at zero, steps that double along its descent
    while they gain; batched over G, with the 3 x 3 algebra in closed form. A batch stops
    when its Newton decrement is below `tol` nats or no step along the Newton direction
    decreases its negative log-likelihood.
    """
    G, M, _ = r3.shape
    w = torch.ones(G, M, dtype=r3.dtype) if w is None else w.to(r3.dtype)
    K = 0 if Bs is None else Bs.shape[-1] // 2
    if K:
        Bs = Bs.expand(G, *Bs.shape[-3:]) if Bs.dim() == 3 else Bs
    x, lo, hi = _variance_start(r3, Bs, w, K)
    if not K:
        return x
    Bj = Bs.reshape(G, M, 3, K, 2).movedim(-2, -3)  # (G, M, K, 3, 2)
    D = torch.cat([torch.eye(3, dtype=r3.dtype).expand(G, M, 1, 3, 3), _mm(Bj, Bj.transpose(-1, -2))], 2)

    def nll(x):
        W, det = _inv3((D * x.exp()[:, None, :, None, None]).sum(2))  # (G, M, 3, 3), (G, M)
        quad = (r3 * _mv(W, r3)).sum(-1)
        val = 0.5 * (w * (torch.log(det.clamp_min(1e-300)) + quad)).sum(-1)
        return torch.where((det <= 0).any(-1), torch.inf, val), W

    f, W = nll(x)
    done = torch.zeros(G, dtype=torch.bool)
    for _ in range(iters):
        v = x.exp()
        u = _mv(W, r3)  # S^-1 r (G, M, 3)
        WD = _mm(W.unsqueeze(2), D)  # (G, M, A, 3, 3)
        Du = _mv(D, u.unsqueeze(2))  # (G, M, A, 3)
        T = (WD.unsqueeze(3) * WD.transpose(-1, -2).unsqueeze(2)).sum((-2, -1))  # tr(W D_a W D_b)
        Q = (Du.unsqueeze(3) * _mv(W.unsqueeze(2), Du).unsqueeze(2)).sum(-1)  # u^T D_a W D_b u
        gv = 0.5 * (w[..., None] * (torch.diagonal(WD, dim1=-2, dim2=-1).sum(-1) - (Du * u[:, :, None]).sum(-1))).sum(1)
        vv = v[:, :, None] * v[:, None, :]
        g = v * gv  # gradient in x
        Hv = 0.5 * (w[..., None, None] * (2 * Q - T)).sum(1)
        H = vv * Hv + torch.diag_embed(g)
        F = vv * 0.5 * (w[..., None, None] * T).sum(1)
        free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))  # bounds that hold stay fixed
        keep = free.to(r3.dtype)
        mask, fixed = keep[:, :, None] * keep[:, None, :], torch.diag_embed(1 - keep)
        g = g * keep
        H, F = H * mask + fixed, F * mask + fixed
        bad = torch.linalg.cholesky_ex(H)[1] > 0
        H = torch.where(bad[:, None, None], F, H)
        dx = -torch.linalg.solve(H, g)
        dec = -(g * dx).sum(-1)  # Newton decrement, nats
        done = done | (dec < tol)
        if bool(done.all()):
            break
        t, searched, x_start = 1.0, done.clone(), x
        for k in range(50):
            xt = torch.minimum(torch.maximum(x + t * dx, lo), hi)
            ft, Wt = nll(xt)
            ok = ~searched & (ft <= f + 1e-4 * (g * (xt - x)).sum(-1))
            x, f = torch.where(ok[:, None], xt, x), torch.where(ok, ft, f)
            W = torch.where(ok[:, None, None, None], Wt, W)
            searched = searched | ok
            if k == 0:
                full = ok  # the full step was taken
            if bool(searched.all()):
                break
            t /= 2
        done = done | ~searched  # no decrease along the Newton direction: optimal to rounding
        # a tau^2 heading for zero (its maximum at the lower bound) takes Newton steps of
        # about -1 in log tau^2 only: after a full step, go on down while it gains
        down = torch.where(dx < -0.5, dx, 0.0)
        down[:, 0] = 0.0
        grow = full & (down < 0).any(-1)
        t = 1.0
        while bool(grow.any()) and t <= 64:
            xt = torch.minimum(torch.maximum(x_start + dx + t * down, lo), hi)
            ft, Wt = nll(xt)
            grow = grow & (ft < f)
            x, f = torch.where(grow[:, None], xt, x), torch.where(grow, ft, f)
            W = torch.where(grow[:, None, None, None], Wt, W)
            t *= 2
    return x


def _fit_variance(r3: np.ndarray, Bs: np.ndarray | None) -> np.ndarray:
    """Maximum-likelihood log variances (1 + K,) for residual rows r3 (M, 3), Bs (M, 3, 2K)
    (see `fit_variances`)."""
    Bt = None if Bs is None or not Bs.shape[-1] else torch.from_numpy(Bs)
    return fit_variances(torch.from_numpy(r3)[None], Bt)[0].numpy()


class _Linear:
    """The linearised refit around a fit: residual r (3N,), base columns A (3N, p0).

    Rows are grouped by pose (`pose` (N,) ids): the F-test and the likelihood-ratio test
    run on pose means (see `diagnose`), the folds keep a pose's rows together.
    """

    def __init__(self, r: np.ndarray, A: np.ndarray, folds: np.ndarray, pose: np.ndarray | None = None):
        A = A / np.linalg.norm(A, axis=0).clip(1e-300)  # unit columns: rank cuts are relative
        self.r, self.A, self.rows = r, A, np.repeat(folds, 3)
        # orthonormal bases with the same rank cut as a candidate's new columns: a column of A
        # in the span of the others (a forward-selection step's chosen columns, of which
        # only some are new) adds nothing; a plain QR would turn its rounding residue into
        # an arbitrary unit column (e.g. one row's x), which the folds then fit from noise
        self.Q = self._new(np.zeros((len(r), 0)), A, len(r))
        self.folds = np.unique(folds)
        pose = np.arange(len(r) // 3) if pose is None else np.asarray(pose)
        _, self.pose_of_row, self.counts = np.unique(pose, return_inverse=True, return_counts=True)
        self.Ab = self.pose_mean(A)
        self.rb = self.pose_mean(r[:, None])[:, 0]
        self.Qb = self._new(np.zeros((len(self.rb), 0)), self.Ab, len(self.rb))

    @property
    def n_poses(self) -> int:
        return len(self.counts)

    def pose_mean(self, X: np.ndarray) -> np.ndarray:
        """Per-pose mean (3P, c) of stacked row values X (3N, c) (x, y, z kept apart)."""
        X3 = X.reshape(-1, 3, X.shape[-1])
        out = np.zeros((self.n_poses, 3, X.shape[-1]))
        np.add.at(out, self.pose_of_row, X3)
        return (out / self.counts[:, None, None]).reshape(-1, X.shape[-1])

    def pose_sum(self, v: np.ndarray) -> np.ndarray:
        """Per-pose sum (P,) of per-row values v (N,)."""
        return np.bincount(self.pose_of_row, weights=v, minlength=self.n_poses)

    @staticmethod
    def _new(Q: np.ndarray, C: np.ndarray | None, n: int) -> np.ndarray:
        if C is None or not C.size:
            return np.zeros((n, 0))
        Cp = C - Q @ (Q.T @ C)
        norms = np.linalg.norm(C, axis=0)
        Cp = Cp[:, norms > 0] / norms[norms > 0]
        if Cp.shape[1] == 0:
            return Cp
        U, s, _ = torch.linalg.svd(torch.from_numpy(Cp), full_matrices=False)
        return U[:, s > RANK_TOL].numpy()  # columns were normalised: s is relative

    def new_columns(self, C: np.ndarray | None) -> np.ndarray:
        """An orthonormal basis (3N, k) of what C adds beyond span(A)."""
        return self._new(self.Q, C, len(self.r))

    def pose_columns(self, C: np.ndarray | None) -> np.ndarray:
        """The same at pose level: an orthonormal basis (3P, kb) of what the pose means of C
        add beyond span(pose means of A)."""
        return self._new(self.Qb, None if C is None or not C.size else self.pose_mean(C), len(self.rb))

    def residual(self, B: np.ndarray) -> np.ndarray:
        """Residual (3N,) of r on [A B] over all rows (B orthonormal, orthogonal to A)."""
        e = self.r - self.Q @ (self.Q.T @ self.r)
        return e - B @ (B.T @ e) if B.size else e

    def pose_residual(self, Bb: np.ndarray) -> np.ndarray:
        """Residual (3P,) of the pose means of r on [pose means of A, Bb]."""
        e = self.rb - self.Qb @ (self.Qb.T @ self.rb)
        return e - Bb @ (Bb.T @ e) if Bb.size else e

    def cross_validate(self, B: np.ndarray, Bs: np.ndarray | None):
        """Held-out distance RMS and mean held-out log-likelihood per row of r on [A B],
        with the residual covariance model Bs (N, 3, K) (None: isotropic).

        X = [Q B] is orthonormal over all rows, so the training normal matrix of a fold is
        I - X_test^T X_test (well conditioned): one small torch solve per fold.
        """
        X = torch.from_numpy(np.hstack([self.Q, B]) if B.size else self.Q)
        r = torch.from_numpy(self.r)
        held = np.empty_like(self.r)
        ll = np.empty(len(self.r) // 3)
        rows3 = self.rows[::3]
        Xr = X.T @ r
        eye = torch.eye(X.shape[1], dtype=X.dtype)
        train = torch.empty(len(self.folds), len(self.r), dtype=r.dtype)  # (F, 3N): test rows unused
        for i, f in enumerate(self.folds):
            test = self.rows == f
            tt = torch.from_numpy(test)
            Xt, rt = X[tt], r[tt]
            if X.shape[1]:
                coef = torch.linalg.solve(eye - Xt.T @ Xt, Xr - Xt.T @ rt)
                held[test] = (rt - Xt @ coef).numpy()
                train[i] = r - X @ coef
            else:
                held[test] = self.r[test]
                train[i] = r
        # the variance model of every fold from its training rows, in one batched fit
        w = torch.from_numpy(rows3[None] != self.folds[:, None])  # (F, N)
        logp = fit_variances(train.reshape(len(self.folds), -1, 3),
                             None if Bs is None or not Bs.shape[-1] else torch.from_numpy(Bs), w).numpy()
        for i, f in enumerate(self.folds):
            t3 = rows3 == f
            ll[t3] = _variance_loglik(held[self.rows == f].reshape(-1, 3), None if Bs is None else Bs[t3], logp[i])
        # per pose, for the paired comparisons (repeats of a pose are one piece of evidence)
        self.last_ll = self.pose_sum(ll)  # (P,) held-out log-likelihood, nats
        self.last_sq = self.pose_sum((held.reshape(-1, 3) ** 2).sum(-1))  # (P,) mm^2
        return _rms(held), float(ll.mean())


def _candidate_specs(robot: Robot, present: dict, ctx) -> list[tuple[str, tuple]]:
    """Effects of the registry (built-in and user effects) not in the model yet; joint
    effects on each joint they do not cover yet; none whose data are missing or that
    refuse the robot or joint (building it or its `check_context` raises InputError, e.g.
    thermal_expansion without temp_c, gear_transmission without gear_ratio, axis_tilt:1)."""
    from torchcal.effects import lookup
    from torchcal.errors import InputError

    out = []
    for name, takes in EFFECTS.items():
        if name in present and not takes:
            continue
        joints = [(j,) for j in range(1, robot.n + 1) if j not in present.get(name, ())] if takes else [()]
        for js in joints:
            try:  # the data lack a column, or the effect does not exist there (axis_tilt:1)
                lookup(name)(robot, js).check_context(ctx)
            except InputError:
                continue
            out.append((name, js))
    return out


def _spec(name, joints):
    return name if not joints else f"{name}:{','.join(map(str, joints))}"


def candidate_columns(robot, base_model: CalibrationModel, theta, ctx, spec: str) -> np.ndarray:
    """d model / d candidate parameters at theta (3N, k), the candidate's values at zero."""
    aug = CalibrationModel(robot, base_model.specs() + [spec], points=base_model.points or None)
    k = aug.n_params - base_model.n_params
    if k == 0:  # an effect with no parameters here (e.g. a user effect on joint 1): nothing to add
        return np.zeros((3 * ctx.n_rows, 0))

    C = aug.jacobian(torch.cat([theta, theta.new_zeros(k)]), ctx)[..., base_model.n_params:]
    return C.reshape(-1, k).detach().numpy()


def all_candidate_columns(robot, base_model: CalibrationModel, theta, ctx, specs) -> dict:
    """`candidate_columns` of every (name, joints) in specs, from one forward-mode pass: the
    candidates are added side by side as separate effects at zero, where each is the
    identity, so each one's columns are those of the model with it alone."""
    specs = list(specs)
    if not specs:
        return {}
    extra = [build(_spec(n, j), robot) for n, j in specs]
    aug = CalibrationModel(robot, list(base_model.effects) + extra)
    k = aug.n_params - base_model.n_params

    C = aug.jacobian(torch.cat([theta, theta.new_zeros(k)]), ctx)[..., base_model.n_params:]
    C = C.reshape(-1, k).detach().numpy()
    out, start = {}, 0
    for spec, e in zip(specs, extra):
        out[spec] = C[:, start:start + e.n_params]
        start += e.n_params
    return out


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


def _not_better(best, c, attr: str, sign: float) -> bool:
    """True when `best` does not beat `c` significantly per pose: the paired difference of
    the per-pose held-out values (sign * (best - c), positive = best better) has a mean
    below two standard errors."""
    diff = sign * (getattr(best, attr) - getattr(c, attr))
    return diff.mean() < 2 * diff.std(ddof=1) / np.sqrt(len(diff))


def rank(cands: list) -> list:
    """Candidates best first: those significant by a deterministic part, by held-out RMS;
    then those significant by a random part only, by score; then the rest, by score."""
    return sorted(cands, key=lambda c: (0, c.cv_rms_mm) if c.deterministic else
                  (1, -c.score) if c.significant else (2, -c.score))


def select(cands: list) -> Candidate | None:
    """The verdict among ranked candidates, or None.

    A predictable (deterministic) explanation comes first: a random-only term (random
    clearance as a variance) can also soak up structure that some deterministic effect
    predicts, so it is named only when no deterministic candidate is significant.
    Within a tier, a simpler candidate (fewer new parameters) that the best does not beat
    significantly per pose is preferred (held-out squared error for deterministic terms,
    log-likelihood for random ones): e.g. an encoder-scale error over a limited joint
    range is fitted about as well by four harmonics, and the one-parameter effect is named.
    """
    det = [c for c in cands if c.deterministic]
    tier = det or [c for c in cands if c.significant]
    if not tier:
        return None
    best = tier[0]
    attr, sign = ("held_out_sq", -1.0) if det else ("held_out_ll", 1.0)
    close = [c for c in tier[1:] if c.k < best.k and _not_better(best, c, attr, sign)]
    return min(close, key=lambda c: (c.k, tier.index(c)), default=best)


def random_clearance_basis(robot: Robot, ctx, xyz: torch.Tensor, joint: int) -> np.ndarray:
    """(N, 3, 2) TCP displacement in mm per mrad of random tilt of `joint`'s axis."""
    from torchcal.effects.joint_clearance import random_basis

    return (random_basis(ctx, joint, xyz) * MRAD).numpy()


def diagnose(robot: Robot, m: Measurements, effects=(), folds: int = 5, seed: int = 0,
             alpha: float = ALPHA, min_gain: float = MIN_GAIN, base_fit: FitResult | None = None) -> Diagnosis:
    """Rank the candidate effects missing from `robot` + `effects` on measurements m."""
    specs = [str(s) for s in parse_specs(list(effects), robot.n)] if effects else []
    model = CalibrationModel.for_measurements(robot, specs, m)  # one tool offset per point id
    ctx = context_of(robot, m)
    if base_fit is None:
        base_fit = fit(model, ctx, m.xyz)
    theta = base_fit.theta
    r = base_fit.residuals.reshape(-1).numpy()
    A = model.jacobian(theta, ctx).reshape(-1, model.n_params)[:, base_fit.report.free].detach().numpy()
    folds_ = fold_ids(m.pose, folds, seed)
    pose_np = m.pose.cpu().numpy()
    lin = _Linear(r, A, folds_, pose_np)
    n_eq = len(r)
    present = {s.name: s.joints for s in parse_specs(specs, robot.n)} if specs else {}
    cands_specs = _candidate_specs(robot, present, ctx)
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
        Bb = lin_.pose_columns(C)
        kb = Bb.shape[1]
        e0b, e1b = lin_.pose_residual(np.zeros((len(lin_.rb), 0))), lin_.pose_residual(Bb)
        rss0b, rss1b = float(e0b @ e0b), float(e1b @ e1b)
        p_f = 1.0
        if k and kb:
            dof = max(len(lin_.rb) - lin_.Qb.shape[1] - kb, 1)
            F = ((rss0b - rss1b) / kb) / max(rss1b / dof, 1e-300)
            p_f = float(scipy.stats.f.sf(F, kb, dof))
        Bs_all = Bs_in if Bs is None else (Bs if Bs_in is None else np.concatenate([Bs_in, Bs], -1))
        cv, ll = lin_.cross_validate(B, Bs_all)
        ll_rows, sq_rows = lin_.last_ll, lin_.last_sq
        gain = (base_cv - cv) / max(base_cv, 1e-300)
        score = ll - base_ll
        significant = deterministic = k > 0 and p_f < level and gain >= min_gain
        p_lr = 1.0
        if Bs is not None:  # likelihood-ratio test of the random part, on pose means
            e3 = e1b.reshape(-1, 3)
            ll0 = _variance_loglik(e3, pose_basis(Bs_in), _fit_variance(e3, pose_basis(Bs_in))).sum()
            ll1 = _variance_loglik(e3, pose_basis(Bs_all), _fit_variance(e3, pose_basis(Bs_all))).sum()
            p_lr = float(0.5 * scipy.stats.chi2.sf(max(2 * (ll1 - ll0), 0.0), Bs.shape[-1] // 2))
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

    columns, variance = all_candidate_columns(robot, model, theta, ctx, cands_specs), {}
    for name, joints in cands_specs:
        if name == "joint_clearance":
            variance[(name, joints)] = random_clearance_basis(robot, ctx, m.xyz, joints[0])
    base_cv, base_ll = lin.cross_validate(np.zeros((n_eq, 0)), None)
    cands = [judge(n, j, lin, None, C, variance.get((n, j)), base_cv, base_ll, level)
             for (n, j), C in columns.items()]
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
            lin_in = _Linear(r, np.hstack([A, C_in]), folds_, pose_np)
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
                                (base_cv - cv) / max(base_cv, 1e-300), deterministic=verdict.deterministic)
            cands.insert(0, verdict)
    where = where_it_fails(robot, m, base_fit.residuals)
    # what remains: the linearised residual with the verdict added (the baseline's without)
    C_v = None if verdict is None else (
        np.hstack([columns[(verdict.effect, (j,))] for j in verdict.joints]) if verdict.joints
        else columns[(verdict.effect, ())])
    rest = lin.residual(lin.new_columns(C_v)).reshape(-1, 3)
    rest_un = unexplained(robot, m, torch.from_numpy(rest), seed=seed)
    return Diagnosis(specs, base_fit, base_cv, cands, verdict, where, rest_un)


@dataclass
class Discovery:
    history: list
    final_effects: list
    fit: FitResult
    diagnoses: list
    unexplained: Unexplained | None = None  # what the final model leaves

    def to_dict(self) -> dict:
        return {"history": self.history, "final_effects": self.final_effects,
                "unexplained": None if self.unexplained is None else self.unexplained.to_dict()}


def discover(robot: Robot, m: Measurements, effects=(), folds: int = 5, seed: int = 0,
             max_rounds: int = 6, alpha: float = ALPHA) -> Discovery:
    """Add the best significant effect each round until none is left.

    Multiple testing: round i (0, 1, ...) runs `diagnose` with the budget alpha / 2^(i+1),
    so all the tests of all rounds (and their forward selections) together keep the
    family-wise error below alpha (union bound).

    history[i] = {"effects", "rms_mm" (full nonlinear refit, training), "cv_rms_mm"}.
    """
    specs = [str(s) for s in parse_specs(list(effects), robot.n)] if effects else []
    history, diagnoses = [], []
    ctx = context_of(robot, m)
    base = fit(CalibrationModel.for_measurements(robot, specs, m), ctx, m.xyz)
    for i in range(max_rounds + 1):
        d = diagnose(robot, m, specs, folds=folds, seed=seed, base_fit=base, alpha=alpha / 2 ** (i + 1))
        diagnoses.append(d)
        history.append({"effects": list(specs), "rms_mm": base.rms_mm, "cv_rms_mm": d.baseline_cv_rms_mm})
        if d.verdict is None or len(history) > max_rounds:
            break
        specs = [str(s) for s in parse_specs(specs + [d.verdict.spec], robot.n)]
        base = fit(CalibrationModel.for_measurements(robot, specs, m), ctx, m.xyz)
    return Discovery(history, specs, base, diagnoses, unexplained(robot, m, base.residuals, seed=seed))
