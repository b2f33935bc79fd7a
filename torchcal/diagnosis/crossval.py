"""Cross-validation by pose: the folds, the linearised refit of the pre-screen, and the
full nonlinear refit that decides.

- `LinearRefit`: the residual r of a fit and the base columns A; a candidate's columns C
  are added linearly, the problem solved on the other folds and predicted on the held-out
  one (cheap: a few small solves). The pre-screen ranks candidates with it.
- `refit_cv`: the model itself refitted (`torchcal.calibration.fit.fit`, nonlinear, with
  orientation and the prior exactly as the full fit) on the other folds and predicted on
  the held-out poses. Each fold's refit starts at the full-data fit (warm start), keeps
  its identifiable set and its prior scale rho, so it takes a few iterations.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
import torch

from torchcal.calibration.identifiability import MIN_EQUATIONS_PER_PARAM
from torchcal.folds import fold_of_pose
from torchcal.diagnosis.variance import fit_variances, isotropic_loglik, variance_loglik
from torchcal.errors import InputError

RANK_TOL = 1e-6
REFIT_MAX_ITER = 30


class FewPosesWarning(UserWarning):
    """The folds' training rows carry too few equations for the current model to judge."""


def few_poses(fit, m, folds: np.ndarray) -> str | None:
    """None, or one line when the smallest fold's training rows of `m` (`Measurements`;
    folds (N,) fold label per row) give fewer than MIN_EQUATIONS_PER_PARAM equations (3 per
    row, 6 with rx, ry, rz) per free parameter of `fit` (`FitResult`). With n equations and
    p parameters a least-squares refit predicts a new pose with an error variance of about
    sigma^2 (1 + p / (n - p - 1)): at n = 2 p the held-out error is the noise's times
    sqrt(2) or more, so refit CV figures mostly measure the fold's own fit and an effect
    below that error cannot be told from it (12 simulated kr1000titan poses with backlash
    and thermal expansion, 0.15 mm of error: refit cv 0.50 mm, nothing found)."""
    free = int(fit.report.free.sum())
    per_row = 3 if m.rxyz is None else 6
    labels = np.unique(folds)
    train = min(int((folds != f).sum()) for f in labels) if len(labels) > 1 else len(folds)
    if free == 0 or per_row * train >= MIN_EQUATIONS_PER_PARAM * free:
        return None
    n_poses = len(np.unique(m.pose.cpu().numpy()))
    per_pose = per_row * len(m) / n_poses
    need = int(np.ceil(MIN_EQUATIONS_PER_PARAM * free / per_pose * len(labels) / max(len(labels) - 1, 1)))
    return (f"{m.source or 'data'}: {n_poses} poses judge little: a fold refits {free} free parameters on "
            f"{per_row * train} equations (fewer than {MIN_EQUATIONS_PER_PARAM} per parameter), so refit cv "
            f"errors are mostly the folds' own fit and an effect smaller than them is not found; 'none' is no "
            f"finding; measure at least {need} poses")


def distance_rms(r: np.ndarray) -> float:
    """Distance RMS (mm) of stacked residuals r (3M,)."""
    return float(np.sqrt((r.reshape(-1, 3) ** 2).sum(-1).mean()))


@dataclass
class RefitCV:
    """The held-out error of a model refitted on the other folds.

    cv_rms_mm: distance RMS over all held-out rows; sq (P,) mm^2: per pose id (sorted),
    the sum of its rows' held-out squared distance errors (the paired test's unit);
    error: why a fold could not be refitted (then cv_rms_mm is inf), else None.
    """

    cv_rms_mm: float
    sq: np.ndarray
    error: str | None = None


def fold_fit(full, m, ctx, train: torch.Tensor, *, sigma_mm: float, sigma_deg: float, posterior: bool = True):
    """The fitted model `full` (`FitResult`) refitted on the rows `train` (N,) bool of m:
    from full.theta, with full's identifiable set, plausible scales and prior rho, the
    measured orientations when m has them. InputError when the rows cannot carry it.
    posterior=False: without the covariance (`fit`'s option; a refit used for its theta only).
    Its identifiability report takes `fit`'s rank_shortcut (the same free set; the caller
    reads that and theta)."""
    from torchcal.calibration.fit import fit

    lim = full.plausible_limits or {}
    return fit(full.model, ctx.subset(train), m.xyz[train], theta0=full.theta, free=full.report.free,
               pose=m.pose[train], rotation=None if m.rxyz is None else m.rotation[train],
               sigma_mm=sigma_mm, sigma_deg=sigma_deg, register=False, max_iter=REFIT_MAX_ITER,
               max_length_mm=lim.get("max_length_mm"), max_angle_deg=lim.get("max_angle_deg"),
               prior_sigma_mm=lim.get("prior_sigma_mm"), posterior=posterior, rank_shortcut=True)


def fold_refits(full, m, ctx, folds: np.ndarray, *, sigma_mm: float, sigma_deg: float, posterior: bool = True):
    """Per fold of folds (N,): (test (N,) bool, `fold_fit` on the other folds' rows).

    The refits share one Jacobian of all rows at full.theta and take chord iterations
    from it (`torchcal.calibration.refit`: the same fit to within 1e-9 mm of the
    stationary point, at about two Jacobians' cost instead of one per LM iteration);
    where that does not apply (a robust or damped fit, a fit without its prior's rho, a
    bound reached, no contraction) a fold, and every later fold of the same fit (`_LM_ONLY`),
    is fitted by `fold_fit` itself."""
    from torchcal.calibration import refit as rf

    sh, chord = None, rf.applies(full) and not lm_only(full)
    for f in np.unique(folds):
        test = torch.from_numpy(folds == f)
        res = None
        if chord:
            sh = _shared(full, ctx, m.rotation is not None) if sh is None else sh
            res = rf.refit(full, sh, m, ctx, ~test, sigma_mm=sigma_mm, sigma_deg=sigma_deg, posterior=posterior)
        if res is None:  # and the other folds of this fit by the LM too: they share its conditioning
            if chord:
                mark_lm_only(full)
            chord = False
            res = fold_fit(full, m, ctx, ~test, sigma_mm=sigma_mm, sigma_deg=sigma_deg, posterior=posterior)
        yield test, res


#: the last shared Jacobian (`refit.shared`) with what it is of: (full held weakly, its theta,
#: ctx, orientation, the `Shared`). The stability check refits one model on the halves of
#: every split in turn (one `fold_refits` call per split): they share one evaluation.
_LAST_SHARED: list = []


def _shared(full, ctx, orientation: bool):
    """`refit.shared(full, ctx, orientation)`, evaluated once for consecutive calls on the
    same fitted model (by identity, its theta unchanged), context and orientation flag."""
    from torchcal.calibration import refit as rf

    if _LAST_SHARED:
        ref, theta, c, o, sh = _LAST_SHARED
        if ref() is full and c is ctx and o == orientation and torch.equal(theta, full.theta):
            return sh
    sh = rf.shared(full, ctx, orientation)
    _LAST_SHARED[:] = [weakref.ref(full), full.theta.clone(), ctx, orientation, sh]
    return sh


#: the fitted models (`FitResult`, by identity, held weakly) whose fold refits the chord
#: did not take: their later folds, and the folds of later calls (the split halves of the
#: stability check refit one model many times), go to the LM at once. A cache of a
#: decision only: either path gives the same refit to within 1e-6 mm.
_LM_ONLY: weakref.WeakValueDictionary = weakref.WeakValueDictionary()


def lm_only(full) -> bool:
    """Whether a chord refit of the fitted model `full` fell back to the LM (`_LM_ONLY`)."""
    return _LM_ONLY.get(id(full)) is full


def mark_lm_only(full) -> None:
    """Remember that a chord refit of `full` fell back to the LM (`_LM_ONLY`)."""
    _LM_ONLY[id(full)] = full


def refit_cv(full, m, ctx, folds: np.ndarray, *, sigma_mm: float, sigma_deg: float) -> RefitCV:
    """Pose-grouped K-fold CV of the fitted model `full` (`FitResult`) on measurements m
    (`Measurements`, context ctx), folds (N,) from `torchcal.folds.fold_of_pose`.

    Each fold: `torchcal.calibration.fit.fit` on the other folds' rows, from full.theta,
    with full's identifiable set, plausible scales and prior rho, the measured
    orientations when m has them (weighed by sigma_mm / sigma_deg as in the full fit);
    predicted positions of the held-out rows.
    """
    try:
        err = held_out_errors(full, m, ctx, folds, sigma_mm=sigma_mm, sigma_deg=sigma_deg)
    except InputError as e:
        return RefitCV(float("inf"), np.full(len(np.unique(m.pose.cpu().numpy())), np.inf), str(e))
    return RefitCV(float(np.sqrt(err.mean())), per_pose(m, err))


def held_out_errors(full, m, ctx, folds: np.ndarray, *, sigma_mm: float, sigma_deg: float, accept=None):
    """(N,) mm^2: each row's squared distance error predicted by `full` refitted on the
    other folds of folds (N,) (`fold_refits`); None as soon as `accept(fold_fit)` is false
    for a fold's fit. A fold fit's InputError propagates. The fold fits carry their
    posterior only for `accept` (the held-out errors need their theta only)."""
    err = np.zeros(len(m))
    for test, res in fold_refits(full, m, ctx, folds, sigma_mm=sigma_mm, sigma_deg=sigma_deg,
                                 posterior=accept is not None):
        if accept is not None and not accept(res):
            return None
        with torch.no_grad():
            d = (full.model.predict(res.theta, ctx.subset(test)) - m.xyz[test]).pow(2).sum(-1)
        err[test.numpy()] = d.cpu().numpy()
    return err


def per_pose(m, err: np.ndarray) -> np.ndarray:
    """(P,) the row values err (N,) summed per pose of m, poses in sorted id order."""
    _, pose_of_row = np.unique(m.pose.cpu().numpy(), return_inverse=True)
    return np.bincount(pose_of_row, weights=err)


class LinearRefit:
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
        self._single = bool((self.counts == 1).all())
        self._e0 = self._e0b = None  # `residual` and `pose_residual` of the base alone, on first use
        # one row per pose, in pose order: the pose-level problem is the row-level one
        self.rows_are_poses = self._single and bool((self.pose_of_row == np.arange(len(self.counts))).all())
        self.Ab = self.pose_mean(A)
        self.rb = self.pose_mean(r[:, None])[:, 0]
        self.Qb = self.Q if self.rows_are_poses else self._new(np.zeros((len(self.rb), 0)), self.Ab, len(self.rb))
        self._parts = None  # `_fold_parts`, on first use

    @property
    def n_poses(self) -> int:
        return len(self.counts)

    def pose_mean(self, X: np.ndarray) -> np.ndarray:
        """Per-pose mean (3P, c) of stacked row values X (3N, c) (x, y, z kept apart)."""
        X3 = X.reshape(-1, 3, X.shape[-1])
        out = np.zeros((self.n_poses, 3, X.shape[-1]))
        if self._single:  # one row per pose: the means are the rows, reordered
            out[self.pose_of_row] = X3
            return out.reshape(-1, X.shape[-1])
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
        return U[:, s > RANK_TOL].numpy(force=True)  # columns were normalised: s is relative

    def new_columns(self, C: np.ndarray | None) -> np.ndarray:
        """An orthonormal basis (3N, k) of what C adds beyond span(A)."""
        return self._new(self.Q, C, len(self.r))

    def pose_columns(self, C: np.ndarray | None) -> np.ndarray:
        """The same at pose level: an orthonormal basis (3P, kb) of what the pose means of C
        add beyond span(pose means of A). Where `rows_are_poses` it is `new_columns`(C),
        bit for bit (a caller that has that may take it instead)."""
        return self._new(self.Qb, None if C is None or not C.size else self.pose_mean(C), len(self.rb))

    def residual(self, B: np.ndarray) -> np.ndarray:
        """Residual (3N,) of r on [A B] over all rows (B orthonormal, orthogonal to A)."""
        if self._e0 is None:
            self._e0 = self.r - self.Q @ (self.Q.T @ self.r)
        e = self._e0
        return e - B @ (B.T @ e) if B.size else e.copy()

    def pose_residual(self, Bb: np.ndarray) -> np.ndarray:
        """Residual (3P,) of the pose means of r on [pose means of A, Bb]."""
        if self._e0b is None:
            self._e0b = self.rb - self.Qb @ (self.Qb.T @ self.rb)
        e = self._e0b
        return e - Bb @ (Bb.T @ e) if Bb.size else e.copy()

    def _fold_parts(self):
        """(Q, r, Q^T r, r^T r, per fold (its row indices (numpy), the same (torch), Q_t, r_t,
        Q_t^T Q_t, Q_t^T r_t, r_t^T r_t, its rows' indices in (N,) (numpy)), the training
        weights (F, N), their row counts (F,), each row's fold index (N,)): what every
        `cross_validate` call shares, computed once. Index arrays instead of masks: the
        same elements in the same (ascending) order."""
        if self._parts is None:
            Q, r = torch.from_numpy(self.Q), torch.from_numpy(self.r)
            rows3 = self.rows[::3]
            parts = []
            for f in self.folds:
                ti = np.flatnonzero(self.rows == f)
                tt = torch.from_numpy(ti)  # the rows by index: a gather, not a mask
                Qt, rt = Q[tt], r[tt]
                parts.append((ti, tt, Qt, rt, Qt.T @ Qt, Qt.T @ rt, float(rt @ rt), np.flatnonzero(rows3 == f)))
            w = torch.from_numpy(rows3[None] != self.folds[:, None])  # (F, N) training rows per fold
            fold_of_row = np.searchsorted(self.folds, rows3)  # (N,) index of each row's fold
            n_tr = w.sum(-1).clamp_min(1).numpy(force=True)
            self._parts = (Q, r, Q.T @ r, float(r @ r), parts, w, n_tr, fold_of_row)
        return self._parts

    def cross_validate(self, B: np.ndarray, Bs: np.ndarray | None):
        """Held-out distance RMS and mean held-out log-likelihood per row of r on [A B],
        with the residual covariance model Bs (N, 3, K) (None: isotropic).

        X = [Q B] is orthonormal over all rows, so the training normal matrix of a fold is
        I - X_test^T X_test (well conditioned): one small torch solve per fold.
        """
        Q, r, Qr, rr, parts, w, n_tr, fold_of_row = self._fold_parts()
        Bx = torch.from_numpy(B) if B.size else None
        held = np.empty_like(self.r)
        ll = np.empty(len(self.r) // 3)
        k = Q.shape[1] + (0 if Bx is None else Bx.shape[1])
        Xr = Qr if Bx is None else torch.cat([Qr, Bx.T @ r])
        eye = torch.eye(k, dtype=r.dtype)
        random = Bs is not None and Bs.shape[-1] > 0
        # isotropic: a fold's variance is its training rows' mean square, from the normal
        # equations (no pass over the training rows); with random terms their rows
        train = torch.empty(len(self.folds), len(self.r), dtype=r.dtype) if random else None  # (F, 3N)
        rss = np.empty(len(self.folds))  # isotropic: training residual sum of squares per fold
        for i, (ti, tt, Qt, rt, QtQt, Qtrt, rtrt, _) in enumerate(parts):
            if not k:
                held[ti] = self.r[ti]
                if random:
                    train[i] = r
                rss[i] = rr - rtrt
                continue
            # the blocks of X_t^T X_t and X_t^T r_t for X = [Q B], the Q blocks cached
            if Bx is None:
                XtX, Xtr = QtQt, Qtrt
            else:
                Bt = Bx[tt]
                QtB = Qt.T @ Bt
                XtX = torch.cat([torch.cat([QtQt, QtB], 1), torch.cat([QtB.T, Bt.T @ Bt], 1)])
                Xtr = torch.cat([Qtrt, Bt.T @ rt])
            N_tr, Xr_tr = eye - XtX, Xr - Xtr  # the training rows' normal equations
            coef = torch.linalg.solve(N_tr, Xr_tr)
            q_, b_ = coef[:Q.shape[1]], coef[Q.shape[1]:]
            pred_t = Qt @ q_
            if Bx is not None:
                pred_t = pred_t + Bt @ b_
            held[ti] = (rt - pred_t).numpy(force=True)
            if random:
                train[i] = r - (Q @ q_ if Bx is None else Q @ q_ + Bx @ b_)
            else:  # |r_T - X_T c|^2 = r_T^T r_T - 2 c^T X_T^T r_T + c^T X_T^T X_T c
                rss[i] = rr - rtrt - 2 * float(coef @ Xr_tr) + float(coef @ (N_tr @ coef))
        # the variance model of every fold from its training rows, in one batched fit
        if random:
            logp = fit_variances(train.reshape(len(self.folds), -1, 3), torch.from_numpy(Bs), w).numpy(force=True)
            for i, (ti, *_, t3) in enumerate(parts):
                ll[t3] = variance_loglik(held[ti].reshape(-1, 3), Bs[t3], logp[i])
        else:  # `fit_variances`' closed form: the log mean square of the training rows; the
            # isotropic `variance_loglik` of all rows at once, each with its fold's variance
            logp = np.log(np.maximum(rss / 3 / n_tr, 1e-300))  # (F,)
            s2 = np.array([np.exp(v) for v in logp])  # each as `variance_loglik` takes it
            ll = isotropic_loglik(held.reshape(-1, 3), logp[fold_of_row], s2[fold_of_row])
        # per pose, for the paired comparisons (repeats of a pose are one piece of evidence)
        self.last_ll = self.pose_sum(ll)  # (P,) held-out log-likelihood, nats
        self.last_sq = self.pose_sum((held.reshape(-1, 3) ** 2).sum(-1))  # (P,) mm^2
        return distance_rms(held), float(ll.mean())
