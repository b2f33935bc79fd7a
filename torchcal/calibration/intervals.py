"""Interval identification: repeated measurements -> interval parameter deviations per zone.

docs/paper.md section 5 (eq. 29) with interval errors. The paper leaves open how interval
errors enter eq. 29; torchcal decides it as follows (midpoint-radius propagation through
the linearised solution map).

1. **Interval errors per pose.** Each commanded pose j is measured K times. Per axis the
   measured positions span ``[min_k, max_k]``; with the model's prediction ``p_j`` at the
   current parameters the error interval is ``e_j = [min_k - p_j, max_k - p_j]`` (mm),
   in center/radius form ``e_c``, ``e_r`` (docs/paper.md eq. 23's notation).
2. **Center.** The center parameters ``x_c`` solve the *nonlinear* least-squares problem
   on the interval centers (the mid-range of the repeated measurements) by
   Levenberg-Marquardt (`torchcal.calibration.lm`, eq. 29 with adaptive mu starting at 1e-3), over
   the parameters the identifiability analysis keeps free (`torchcal.calibration.fit`, done at
   nominal: structural identifiability); the others are held at the starting point
   (nominal by default) and reported by name.
3. **Radius.** Linearising the solution map at ``x_c``, a change ``de`` of the stacked
   errors moves the solution by ``dx = S de`` with

       S = (J^T J + mu D^2)^-1 J^T,      D = diag(column norms of J at the start)

   restricted to the free parameters (rows of held parameters are zero). With the
   default ``damping = 0`` (mu = 0) this is the Gauss-Newton map (the converged LM's own
   damping tends to zero), the pseudo-inverse. The image of the error box
   ``{e_c + de : |de| <= e_r}`` under ``x_c + S de`` is a zonotope; its exact interval
   hull has center ``x_c`` and radius ``|S| e_r`` (elementwise absolute value):
   parameter k reaches ``x_c,k +- (|S| e_r)_k`` at the box vertex
   ``de = +-sign(S_k) e_r``, and no point of the box goes further
   (`torchcal.reliability.interval.linear_hull`). It is exact for the linearised map; the nonlinear
   map differs by second-order terms (the deviations are small: test_intervals_identify checks
   that refitting sampled data inside the box lands inside the hull).
4. **Damping (optional).** With ``damping = mu > 0`` a zone is the damped
   least-squares solution of eq. 29 around a prior ``theta0`` (e.g. a global
   calibration): it minimises ``|r(x)|^2 + mu |D (x - theta0)|^2``, and S above (with
   that mu) is its solution map, so the hull stays exact for what is solved.
   ``damping="gcv"`` picks mu per zone, ``"gcv_shared"`` one mu for all zones, by
   generalised cross-validation (`torchcal.calibration.gcv`) on a grid. A zone of few poses then
   moves away from the prior only as far as its own data support.

Batched over zones: `identify_zones` stacks zones with equal numbers of poses into one
batch ``x (B, P)`` and calls `torchcal.calibration.lm.levenberg_marquardt` once per group (per-zone
damping and step acceptance); the result equals fitting the zones one by one.

Units: parameters as in `CalibrationModel.param_units` (rad, mm); errors mm.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch

from torchcal.effects.context import Context, make_context
from torchcal.errors import InputError
from torchcal.calibration.batched import batched_jacobian, batched_predict
from torchcal.calibration.fit import RANK_TOL, Identifiability, identifiability
from torchcal.calibration.gcv import choose_damping, gcv_damping
from torchcal.reliability.interval import Interval
from torchcal.calibration.lm import levenberg_marquardt
from torchcal.calibration.model import CalibrationModel

__all__ = ["PoseIntervals", "pose_intervals", "solution_map", "gcv_damping", "IntervalFit", "IntervalModel",
           "identify_intervals", "identify_zones", "batched_predict", "batched_jacobian"]


# ------------------------------------------------------------------ interval errors

@dataclass(frozen=True, eq=False)
class PoseIntervals:
    """Repeated measurements of each commanded pose, reduced to per-axis intervals.

    Attributes:
        pose: (m,) int64 pose ids, in order of first appearance.
        q: (m, n) rad commanded joint angles (first row of each pose).
        lower: (m, 3) mm per-axis minimum of the measured positions.
        upper: (m, 3) mm per-axis maximum (`interval` is [lower, upper] as an `Interval`).
        count: (m,) int64 repetitions per pose.
        payload_kg: (m,) or None; temp_c: (m,) or None (first row of each pose).
    """

    pose: torch.Tensor
    q: torch.Tensor
    lower: torch.Tensor
    upper: torch.Tensor
    count: torch.Tensor
    payload_kg: torch.Tensor | None = None
    temp_c: torch.Tensor | None = None

    def __post_init__(self):  # checks lower <= upper once (InputError naming the index)
        object.__setattr__(self, "_interval", Interval(self.lower, self.upper))

    @property
    def interval(self) -> Interval:
        """(m, 3) mm per-axis interval [lower, upper] of the measured positions."""
        return self._interval

    @property
    def center(self) -> torch.Tensor:
        """(m, 3) mm mid-range of the repeated measurements."""
        return self._interval.center

    @property
    def radius(self) -> torch.Tensor:
        """(m, 3) mm half-range."""
        return self._interval.radius

    def __len__(self) -> int:
        return self.pose.shape[0]

    def subset(self, index) -> "PoseIntervals":
        pick = lambda t: None if t is None else t[index]  # noqa: E731
        return PoseIntervals(pick(self.pose), pick(self.q), pick(self.lower), pick(self.upper),
                             pick(self.count), pick(self.payload_kg), pick(self.temp_c))

    def context(self, robot) -> Context:
        """Model context with one row per pose (the commanded angles in order)."""
        return make_context(robot, self.q, self.payload_kg, self.temp_c)


def pose_intervals(meas, min_repeats: int = 1) -> PoseIntervals:
    """Group a `torchcal.measurements.Measurements` by pose id into per-axis intervals.

    Rows of one pose must share their commanded joint angles (within 1e-9 rad); raises
    InputError otherwise or when a pose has fewer than `min_repeats` rows.
    """
    pose = meas.pose
    ids, first = [], {}
    for i, p in enumerate(pose.tolist()):
        if p not in first:
            first[p] = i
            ids.append(p)
    slot = {p: k for k, p in enumerate(ids)}
    inv = torch.tensor([slot[p] for p in pose.tolist()], dtype=torch.long)  # (N,) row -> pose
    m = len(ids)
    rows0 = torch.tensor([first[p] for p in ids], dtype=torch.long)
    q = meas.q[rows0]
    if len(meas) and (meas.q - q[inv]).abs().max() > 1e-9:
        bad = int(((meas.q - q[inv]).abs().amax(-1) > 1e-9).nonzero()[0])
        raise InputError(f"measurements: rows of pose {int(pose[bad])} have different joint "
                         f"angles; repeated measurements of one pose must share q1..qN")
    count = torch.bincount(inv, minlength=m)
    if (count < min_repeats).any():
        k = int((count < min_repeats).nonzero()[0])
        raise InputError(f"measurements: pose {ids[k]} has {int(count[k])} row(s); interval "
                         f"identification needs at least {min_repeats} repetitions per pose")
    xyz = meas.xyz
    idx = inv.to(xyz.device)[:, None].expand(-1, 3)
    lo = torch.full((m, 3), float("inf"), dtype=xyz.dtype, device=xyz.device)
    hi = torch.full((m, 3), -float("inf"), dtype=xyz.dtype, device=xyz.device)
    lo = lo.scatter_reduce(0, idx, xyz, "amin")
    hi = hi.scatter_reduce(0, idx, xyz, "amax")
    pick = lambda t: None if t is None else t[rows0.to(t.device)]  # noqa: E731
    return PoseIntervals(torch.tensor(ids, dtype=torch.int64), q, lo, hi, count,
                         pick(meas.payload_kg), pick(meas.temp_c))


# ------------------------------------------------------------------ solution map

def solution_map(J: torch.Tensor, free: torch.Tensor, mu: float = 0.0, scale=None) -> torch.Tensor:
    """Linearised solution map S (P, R) of eq. 29 on the free columns.

    J (R, P) Jacobian of the stacked residual model (mm per parameter unit); free (P,)
    bool. Returns S with ``dx = S de`` (rows of held parameters are zero):
    ``S_free = (J_f^T J_f + mu D^2)^-1 J_f^T``, D = diag(`scale`) restricted to the free
    columns, by default the column norms of ``J_f`` (scale-invariant damping; mu = 0 is
    the Gauss-Newton map, the pseudo-inverse).
    """
    R, P = J.shape
    S = J.new_zeros(P, R)
    idx = free.to(J.device).nonzero().flatten()
    if idx.numel() == 0:
        return S
    Jf = J[:, idx]
    d = (Jf.norm(dim=0) if scale is None else scale.to(J)[idx]).clamp_min(1e-300)
    Js = Jf / d
    A = Js.T @ Js + mu * torch.eye(idx.numel(), dtype=J.dtype, device=J.device)
    S[idx] = torch.linalg.solve(A, Js.T) / d[:, None]
    return S


# ------------------------------------------------------------------ results

@dataclass(eq=False)
class IntervalFit:
    """Interval parameters of one zone (or of a global calibration).

    Attributes:
        model: the `CalibrationModel`.
        theta: (P,) center parameters x_c (rad, mm as `model.param_units()`).
        radius: (P,) radius |S| e_r (0 for held parameters).
        report: identifiability at the starting point (held names, rank, condition, O1..O5).
        S: (P, 3m) linearised solution map at x_c (mm -> parameter units).
        residual_mm: (m, 3) interval centers minus model at x_c.
        error_radius_mm: (m, 3) half-range of the repeated measurements.
        n_iter: LM iterations; converged: LM convergence rule met; status: 'converged',
            'stalled' or 'max_iterations' (`torchcal.calibration.lm.LMStatus`).
        damping: mu of eq. 29 used for this zone (0: plain least squares).
    """

    model: CalibrationModel
    theta: torch.Tensor
    radius: torch.Tensor
    report: Identifiability
    S: torch.Tensor
    residual_mm: torch.Tensor
    error_radius_mm: torch.Tensor
    n_iter: int
    converged: bool
    damping: float = 0.0
    status: str = "converged"

    @property
    def free(self) -> torch.Tensor:
        """(P,) bool identified parameters."""
        return self.report.free

    @property
    def interval(self) -> Interval:
        """(P,) parameter intervals [theta - radius, theta + radius]."""
        return Interval.from_center_radius(self.theta, self.radius)

    @property
    def rms_mm(self) -> float:
        """RMS distance between the interval centers and the fitted model, mm."""
        return float(self.residual_mm.norm(dim=-1).pow(2).mean().sqrt())

    def rows(self, degrees: bool = True) -> list[dict]:
        """Per identified parameter: {"name", "unit", "centre" (the center value; the JSON key
        keeps its name), "lower", "upper"} (angles in degrees)."""
        out = []
        names, units = self.model.param_names(), self.model.param_units()
        for k in self.free.nonzero().flatten().tolist():
            f = 180.0 / torch.pi if (degrees and units[k] == "rad") else 1.0
            c, r = float(self.theta[k]) * f, float(self.radius[k]) * f
            out.append({"name": names[k], "unit": "deg" if f != 1.0 else units[k],
                        "centre": c, "lower": c - r, "upper": c + r})
        return out

    def to_dict(self) -> dict:
        """JSON-ready: centre/lower/upper for every parameter (model units), report."""
        return {"theta": self.theta.tolist(), "radius": self.radius.tolist(),
                "lower": (self.theta - self.radius).tolist(), "upper": (self.theta + self.radius).tolist(),
                "free": self.free.tolist(), "identifiability": self.report.to_dict(),
                "rms_mm": self.rms_mm, "n_iter": self.n_iter, "converged": self.converged,
                "status": self.status, "damping": self.damping,
                "parameters": self.rows(degrees=True)}


# ------------------------------------------------------------------ identification

def _check_zone(model, ctx, data, what):
    if not isinstance(data, PoseIntervals):
        raise InputError(f"{what}: expected PoseIntervals, got {type(data).__name__}")
    if ctx.n_rows != len(data):
        raise InputError(f"{what}: context has {ctx.n_rows} rows but the data {len(data)} poses")
    model.check_context(ctx)


def identify_zones(model: CalibrationModel, zones, free=None, damping=0.0,
                   rank_tol: float = RANK_TOL, max_iter: int = 100, theta0=None) -> list[IntervalFit]:
    """Interval identification of several zones, batched.

    Args:
        model: the `CalibrationModel` (geometric deviations + effects).
        zones: list of `PoseIntervals` (contexts built from their q) or of
            ``(Context, PoseIntervals)`` pairs.
        free: (P,) bool candidate parameters (default `model.default_free()`); per zone
            the identifiability analysis at theta0 may hold more (reported by name).
        damping: mu of eq. 29, relative to the squared column norms of the Jacobian at
            theta0 (scale-invariant). 0 (default): plain least squares (LM's own damping
            goes to zero; the solution map is Gauss-Newton's). A number > 0: the damped
            solution, i.e. the minimiser of ``|r(x)|^2 + mu |D (x - theta0)|^2``, which
            shrinks each zone towards theta0 (e.g. a global calibration); the solution map
            is then the damped one, and the interval hull is exact for it. ``"gcv"``: mu
            per zone by generalised cross-validation (`gcv_damping`).
        rank_tol: identifiability threshold (`torchcal.calibration.fit.identifiability`).
        max_iter: LM iterations at most.
        theta0: (P,) starting point; held parameters stay at its values (default nominal).

    Zones with equal numbers of poses share one LM call. Returns one `IntervalFit` per
    zone, in order.
    """
    if len(zones) == 0:
        raise InputError("identify_zones: no zones given")
    if not (damping in ("gcv", "gcv_shared") or (isinstance(damping, (int, float)) and damping >= 0)):
        raise InputError(f"damping: expected a number >= 0, 'gcv' or 'gcv_shared', got {damping!r}")
    pairs = []
    for z, item in enumerate(zones):
        if isinstance(item, PoseIntervals):
            item = (item.context(model.robot), item)
        ctx, data = item
        _check_zone(model, ctx, data, f"zone {z}")
        pairs.append((ctx, data))
    cand = model.default_free() if free is None else torch.as_tensor(free, dtype=torch.bool)
    x0 = model.zeros() if theta0 is None else torch.as_tensor(theta0).to(model.zeros())
    names = model.param_names()
    P = model.n_params
    groups: dict[int, list[int]] = {}
    for z, (_, d) in enumerate(pairs):
        groups.setdefault(len(d), []).append(z)
    fits: list[IntervalFit | None] = [None] * len(pairs)
    for m, members in groups.items():
        ctxs = [pairs[z][0] for z in members]
        datas = [pairs[z][1] for z in members]
        B = len(members)
        xb = x0.expand(B, P).clone()
        # structural identifiability: analysed at nominal, whatever theta0 is
        Jn = batched_jacobian(model, torch.zeros_like(xb), ctxs)  # (B, m, 3, P)
        reports = [identifiability(Jn[b], names, cand, rank_tol) for b in range(B)]
        J0 = Jn if theta0 is None else batched_jacobian(model, xb, ctxs)
        for b, rep in enumerate(reports):
            if 3 * m <= rep.rank and damping == 0:
                raise InputError(f"zone {members[b]}: {m} poses give {3 * m} equations for "
                                 f"{rep.rank} identifiable parameters; need more poses")
        freeb = torch.stack([r.free for r in reports]).to(xb.device)  # (B, P)
        target = torch.stack([d.center for d in datas]).to(xb)  # (B, m, 3)
        J0f = J0.reshape(B, 3 * m, P)
        scale = J0f.norm(dim=1).clamp_min(1e-300)  # (B, P) column norms at theta0
        if damping in ("gcv", "gcv_shared"):
            r0 = (target - batched_predict(model, xb, ctxs)).reshape(B, -1)
            mus = choose_damping(J0f, r0, freeb, damping)
        else:
            mus = [float(damping)] * B
        mu_t = torch.tensor(mus, dtype=xb.dtype, device=xb.device)
        prior = (mu_t.sqrt()[:, None] * scale) * freeb  # (B, P) rows sqrt(mu) D on free params
        damped = bool((mu_t > 0).any())

        def residual_fn(x):  # (B, P) -> (B, 3m [+ P])
            r = (batched_predict(model, x, ctxs) - target).reshape(x.shape[0], -1)
            return torch.cat([r, prior * (x - x0)], dim=1) if damped else r

        def jacobian_fn(x):  # (B, 3m [+ P], P)
            J = batched_jacobian(model, x, ctxs).reshape(x.shape[0], 3 * m, P)
            return torch.cat([J, torch.diag_embed(prior)], dim=1) if damped else J

        res = levenberg_marquardt(residual_fn, xb, free=freeb, jacobian_fn=jacobian_fn,
                                  max_iter=max_iter)
        J = batched_jacobian(model, res.x, ctxs).reshape(B, 3 * m, P)
        pred = batched_predict(model, res.x, ctxs)
        for b, z in enumerate(members):
            S = solution_map(J[b], freeb[b], mus[b], scale=scale[b])  # (P, 3m)
            er = datas[b].radius.to(xb).reshape(-1)  # (3m,)
            radius = S.abs() @ er
            fits[z] = IntervalFit(model, res.x[b].clone(), radius, reports[b], S,
                                  target[b] - pred[b], datas[b].radius.to(xb),
                                  int(res.n_iter[b]), bool(res.converged[b]), mus[b],
                                  res.status_labels()[b])
    return fits  # type: ignore[return-value]


def identify_intervals(model: CalibrationModel, data: PoseIntervals, ctx: Context | None = None,
                       **kwargs) -> IntervalFit:
    """Interval identification of one zone (see `identify_zones` for the arguments)."""
    item = data if ctx is None else (ctx, data)
    return identify_zones(model, [item], **kwargs)[0]


# ------------------------------------------------------------------ the model of all zones


@dataclass(eq=False)
class IntervalModel:
    """Interval parameters per zone (or one global zone), with the partition that assigns
    targets to zones. Plain data; its file (the MODEL.json of ``torchcal calibrate``) is
    written and read by `torchcal.io.interval_model`.

    Values in the model's units (mm, rad, ...); zones 1-based. Without a partition there
    is exactly one zone and every target uses it.

    Attributes:
        model: the `CalibrationModel`.
        theta: (Z, P) center parameters per zone; lower, upper: (Z, P) interval bounds.
        free: (Z, P) bool identified parameters.
        zones: per zone dict (zone, level, poses, held, rms_mm, damping).
        partition: a `torchcal.partition.zones.Partition` or None.
        method: how the zones were fitted ("global", "independent", "damped").
        provenance: free-form dict (input file, versions).
        global_fit: the global `IntervalFit` (its `report`, `rms_mm`) when the model comes
            from `torchcal.calibrate`, else None; not stored in the file.
        q_range: (2, n) [min; max] commanded q of the calibration data, rad / mm
            (`torchcal.calibration.joint_range`), None when unknown.
        seed_poses: (K, n) a few calibration poses that seed compensate, rad / mm, or None.
        residual_model: the non-physical residual stage of a fitted model read as one
            zone (`torchcal.calibration.residual_model`), else None.
    """

    model: CalibrationModel
    theta: torch.Tensor
    lower: torch.Tensor
    upper: torch.Tensor
    free: torch.Tensor
    zones: list
    partition: object = None
    method: str = "global"
    provenance: dict | None = None
    global_fit: object = None
    q_range: torch.Tensor | None = None
    residual_model: object = None
    seed_poses: torch.Tensor | None = None

    @property
    def n_zones(self) -> int:
        return self.theta.shape[0]

    @classmethod
    def single(cls, model, theta: torch.Tensor, free: torch.Tensor | None = None, q_range=None) -> "IntervalModel":
        """One zone holding a fitted model's parameters theta (P,) (method "fit"); free (P,)
        bool identified parameters (default all)."""
        free = torch.ones(theta.shape[-1], dtype=torch.bool) if free is None else free
        return cls(model, theta[None], theta[None], theta[None], free[None],
                   [{"zone": 1, "level": None, "poses": None, "held": [], "rms_mm": None, "damping": 0.0}],
                   None, "fit", q_range=q_range)

    @classmethod
    def of_fit(cls, fitted) -> "IntervalModel":
        """One zone holding a fitted model (`FitResult`): its parameters, identified set,
        calibrated range, residual stage, and its training rms as the zone's ``rms_mm``."""
        im = cls.single(fitted.model, fitted.theta, fitted.report.free, q_range=fitted.q_range)
        im.zones[0]["rms_mm"] = fitted.training_rms_mm
        return dataclasses.replace(im, residual_model=fitted.residual_model, provenance=fitted.provenance,
                                   seed_poses=getattr(fitted, "seed_poses", None))

    @classmethod
    def from_fits(cls, fits: list, partition=None, levels=None, poses=None, method: str = "global",
                  provenance=None) -> "IntervalModel":
        """From one `IntervalFit` per zone (zone order = partition zone 1..Z)."""
        model = fits[0].model
        zones = []
        for z, f in enumerate(fits):
            zones.append({"zone": z + 1, "level": None if levels is None else int(levels[z]),
                          "poses": None if poses is None else int(poses[z]), "held": f.report.held,
                          "rms_mm": f.rms_mm, "damping": f.damping})
        th = torch.stack([f.theta for f in fits])
        rad = torch.stack([f.radius for f in fits])
        return cls(model, th, th - rad, th + rad, torch.stack([f.free for f in fits]), zones, partition,
                   method, provenance)

    def assign(self, targets: torch.Tensor) -> torch.Tensor:
        """(M,) int64 zone ids 1..Z of target positions (M, 3) mm, numbered as in the
        partition (`Partition.assign`) and the files; 1 for every target without a partition.
        Row ``zone - 1`` of `theta` holds that zone's parameters."""
        if self.partition is None:
            return torch.ones(targets.shape[0], dtype=torch.long)
        return self.partition.assign(targets)
