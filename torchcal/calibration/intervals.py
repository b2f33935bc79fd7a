"""Interval identification: repeated measurements -> interval parameter deviations per zone.

docs/paper.md section 5 (eq. 29) with interval errors. The paper leaves open how interval
errors enter eq. 29; torchcal decides it as follows (midpoint-radius propagation through
the linearised solution map).

1. **Interval errors per pose.** Each commanded pose j is measured K times. Per axis the
   measured positions span ``[min_k, max_k]``; with the model's prediction ``p_j`` at the
   current parameters the error interval is ``e_j = [min_k - p_j, max_k - p_j]`` (mm),
   in center/radius form ``e_c``, ``e_r`` (docs/paper.md eq. 23's notation).
2. **Center.** The center parameters ``x_c`` solve the *nonlinear* least-squares problem
   on the interval centers (the mid-range of the repeated measurements) by the one fit of
   torchcal (`torchcal.calibration.fit.fit`: Levenberg-Marquardt, eq. 29 with adaptive mu
   starting at 1e-3; here without the plausibility prior and without registration), over
   the parameters the identifiability analysis keeps free (a cold start without damping
   from the closed-form registration of the frame, as `fit` starts; `torchcal.calibration.fit`, done at
   the nominal robot in the starting point's measuring frames (base frame, tool offset):
   structural identifiability, with the gauge `fit` uses: of a base frame and
   joint 1's dtheta / dd, or a tool offset and the last link's length, the frames are kept
   and the robot's deviations held, so a tracker's rotation about z and height land in the
   base frame, not in joint 1); the others are held at the starting point (nominal by
   default) and reported by name. A cold start without damping is analysed once more at
   its fitted frames and refitted when they free more (as `fit` rechecks): at a zero tool
   offset the TCP lies on the last joint's axis and joint 5's da and dalpha move nothing,
   while with a reflector 290 mm off the flange they do.
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

The result of each zone is a `FitResult` (the one fitted-model type) with ``radius`` (the
half-widths ``|S| e_r``) and ``damping`` (mu) set; `parameter_intervals` lists its
intervals. Zones are fitted one after another by the same `fit` as ``torchcal fit``.

Units: parameters as in `CalibrationModel.param_units` (rad, mm); errors mm.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch

from torchcal.effects.context import Context, approach_directions, make_context
from torchcal.errors import DataError, InputError
from torchcal.calibration.fit import RANK_TOL, FitResult, Identifiability, fit, identifiability
from torchcal.calibration.identifiability import check_enough_rows
from torchcal.calibration.gcv import choose_damping, gcv_damping
from torchcal.reliability.interval import Interval
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.plausibility import plausible_scales

__all__ = ["PoseIntervals", "pose_intervals", "solution_map", "gcv_damping", "parameter_intervals",
           "identify_intervals", "identify_zones"]


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
        payload_kg: (m,) or None; temp_c: (m,) or None (first row of each pose, or the
            mid-range of its rows: `pose_intervals`).
        approach: (m, n) +1 / -1 or None: the direction each joint last moved in to reach
            the pose, from the order of the measurement rows (`approach_directions` over
            the session, its q_prev when given; the first row of each pose), so that a
            subset (a zone) keeps the session's directions; None: from the order of the
            poses (of the subset) as given.
        mixed: (m,) bool or None: the pose's rows were approached from different
            directions (an interval of its repeats mixes them).
    """

    pose: torch.Tensor
    q: torch.Tensor
    lower: torch.Tensor
    upper: torch.Tensor
    count: torch.Tensor
    payload_kg: torch.Tensor | None = None
    temp_c: torch.Tensor | None = None
    approach: torch.Tensor | None = None
    mixed: torch.Tensor | None = None

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
                             pick(self.count), pick(self.payload_kg), pick(self.temp_c), pick(self.approach),
                             pick(self.mixed))

    def context(self, robot) -> Context:
        """Model context with one row per pose (the commanded angles in order; the approach
        directions of the rows when recorded)."""
        ctx = make_context(robot, self.q, self.payload_kg, self.temp_c)
        return ctx if self.approach is None else dataclasses.replace(ctx, approach=self.approach.to(ctx.q))


def pose_intervals(meas, min_repeats: int = 1, rows: bool = False) -> PoseIntervals:
    """Group a `torchcal.measurements.Measurements` by pose id into per-axis intervals.

    Rows of one pose must share their commanded joint angles (within 1e-9 rad); raises
    InputError otherwise or when a pose has fewer than `min_repeats` rows. rows: the
    conditions of the pose's rows, not of its first row: their approach directions in the
    session (``approach``, ``mixed``; `PoseIntervals`), and payload_kg and temp_c the
    mid-range of the rows (the interval's centre is the mid-range of the positions, which
    an effect linear in them, thermal expansion, compliance, takes at their mid-range; a
    pose visited while the cell warmed spans several degrees).
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
        raise InputError(f"{meas.source or 'measurements'}: rows of pose {int(pose[bad])} have different joint "
                         f"angles; repeated measurements of one pose must share q1..qN")
    count = torch.bincount(inv, minlength=m)
    if (count < min_repeats).any():
        k = int((count < min_repeats).nonzero()[0])
        raise InputError(f"{meas.source or 'measurements'}: pose {ids[k]} has {int(count[k])} row(s); interval "
                         f"identification needs at least {min_repeats} repetitions per pose")
    xyz = meas.xyz
    idx = inv.to(xyz.device)[:, None].expand(-1, 3)
    lo = torch.full((m, 3), float("inf"), dtype=xyz.dtype, device=xyz.device)
    hi = torch.full((m, 3), -float("inf"), dtype=xyz.dtype, device=xyz.device)
    lo = lo.scatter_reduce(0, idx, xyz, "amin")
    hi = hi.scatter_reduce(0, idx, xyz, "amax")
    pick = lambda t: None if t is None else t[rows0.to(t.device)]  # noqa: E731
    app = mixed = None
    if rows:
        mid = lambda t: None if t is None else (  # noqa: E731
            t.new_full((m,), float("inf")).scatter_reduce(0, inv.to(t.device), t, "amin")
            + t.new_full((m,), -float("inf")).scatter_reduce(0, inv.to(t.device), t, "amax")) / 2
        pick = mid
        d = approach_directions(meas.q, meas.q_prev)  # (N, n) in the order measured
        app = d[rows0.to(d.device)]
        mixed = torch.zeros(m, dtype=torch.bool).index_put_(
            (inv,), (d != app[inv.to(d.device)]).any(-1).cpu(), accumulate=True)
    return PoseIntervals(torch.tensor(ids, dtype=torch.int64), q, lo, hi, count,
                         pick(meas.payload_kg), pick(meas.temp_c), app, mixed)


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


# ------------------------------------------------------------------ intervals of a fit

def parameter_intervals(res: FitResult, degrees: bool = True) -> list[dict]:
    """Per identified parameter of an interval fit (``res.radius`` set): {"name", "unit",
    "centre" (the center value; the JSON key keeps its name), "lower", "upper"} (angles in
    degrees when `degrees`)."""
    out = []
    names, units = res.model.param_names(), res.model.param_units()
    for k in res.report.free.nonzero().flatten().tolist():
        f = 180.0 / torch.pi if (degrees and units[k] == "rad") else 1.0
        c, r = float(res.theta[k]) * f, float(res.radius[k]) * f
        out.append({"name": names[k], "unit": "deg" if f != 1.0 else units[k],
                    "centre": c, "lower": c - r, "upper": c + r})
    return out


# ------------------------------------------------------------------ identification

def _check_zone(model, ctx, data, what):
    if not isinstance(data, PoseIntervals):
        raise InputError(f"{what}: expected PoseIntervals, got {type(data).__name__}")
    if ctx.n_rows != len(data):
        raise InputError(f"{what}: context has {ctx.n_rows} rows but the data {len(data)} poses")
    model.check_context(ctx)


def identify_zones(model: CalibrationModel, zones, free=None, damping=0.0,
                   rank_tol: float = RANK_TOL, max_iter: int = 100, theta0=None, labels=None) -> list[FitResult]:
    """Interval identification of several zones, each by the one fit (`torchcal.calibration.fit.fit`).

    Args:
        model: the `CalibrationModel` (geometric deviations + effects).
        zones: list of `PoseIntervals` (contexts built from their q) or of
            ``(Context, PoseIntervals)`` pairs.
        free: (P,) bool candidate parameters (default `model.default_free()`); per zone
            the identifiability analysis at nominal may hold more (reported by name).
        damping: mu of eq. 29, relative to the squared column norms of the Jacobian at
            theta0 (scale-invariant). 0 (default): plain least squares (LM's own damping
            goes to zero; the solution map is Gauss-Newton's). A number > 0: the damped
            solution, i.e. the minimiser of ``|r(x)|^2 + mu |D (x - theta0)|^2``, which
            shrinks each zone towards theta0 (e.g. a global calibration); the solution map
            is then the damped one, and the interval hull is exact for it. ``"gcv"``: mu
            per zone by generalised cross-validation (`gcv_damping`), ``"gcv_shared"``:
            one mu for all zones.
        rank_tol: identifiability threshold (`torchcal.calibration.fit.identifiability`).
        max_iter: LM iterations at most.
        theta0: (P,) starting point; held parameters stay at its values (default nominal).
        labels: what each zone is called in an error (default "zone 1", "zone 2", ...:
            the order given; a caller passing a subset names them by the partition's numbers).

    Each zone is `fit` on its interval centers from theta0 with the damping, without the
    plausibility prior and without registration, on the parameters identifiable at the
    nominal robot in theta0's measuring frames (structural identifiability, whatever
    theta0's robot deviations are; a cold start without damping once more at its fitted
    frames, module doc). Returns one `FitResult` per zone, in
    order, with ``radius`` (the interval half-widths |S| e_r) and ``damping`` set; its
    ``residuals`` are the interval centers minus the model, one row per pose.
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
    frames = ~torch.isfinite(plausible_scales(model))  # the gauge of `fit`: frames before joint 1's dtheta, dd
    reports, J0s, r0s = [], [], []
    for z, (ctx, data) in enumerate(pairs):
        rep = _structural(model, ctx, x0, cand, frames, rank_tol)
        m = len(data)
        if 3 * m <= rep.rank and damping == 0:  # the message of `fit` (the model's count at generic poses)
            try:
                check_enough_rows(rep, 3 * m, model, ctx, cand, rank_tol)
            except DataError as exc:
                raise DataError(f"{f'zone {z + 1}' if labels is None else labels[z]}: {exc.message}") from None
        reports.append(rep)
        if damping in ("gcv", "gcv_shared"):
            J0s.append(model.jacobian(x0, ctx).reshape(3 * m, -1))
            r0s.append((data.center.to(x0) - model.predict(x0, ctx)).reshape(-1))
    if damping in ("gcv", "gcv_shared"):
        mus = choose_damping(J0s, r0s, torch.stack([r.free for r in reports]), damping,
                             labels=[f"zone {z + 1}" for z in range(len(pairs))] if labels is None else labels)
    else:
        mus = [float(damping)] * len(pairs)
    cold = theta0 is None and damping == 0  # plain least squares from nominal: where it starts is free
    fits = [_identify(model, ctx, data, rep, _registered(model, ctx, data, x0) if cold else x0, mu, rank_tol,
                      max_iter) for (ctx, data), rep, mu in zip(pairs, reports, mus)]
    if cold and bool(frames.any()):  # a cold start analysed the frames at zero
        for k, ((ctx, data), rep, res) in enumerate(zip(pairs, reports, fits)):
            again = _structural(model, ctx, res.theta, cand, frames, rank_tol)  # at the fitted frames
            if bool((again.free & ~rep.free).any()) and 3 * len(data) > again.rank:
                fits[k] = _identify(model, ctx, data, again, res.theta, 0.0, rank_tol, max_iter)
    return fits


def _registered(model, ctx, data: PoseIntervals, x0: torch.Tensor) -> torch.Tensor:
    """(P,) x0 with a base_frame at the closed-form registration of the model onto the
    zone's interval centers (`fit`'s start, `torchcal.calibration.registration.register_frame`),
    x0 itself without a base_frame or with fewer than 3 poses. From an identity frame, a
    tracker 2.5 m away and turned stopped one UR5e zone of 10 poses at rms 21 mm."""
    from torchcal.calibration.registration import register_frame

    if len(data) < 3 or not any(e.name == "base_frame" for e in model.effects):
        return x0
    return register_frame(model, ctx, data.center.to(x0), x0)[0]


def _structural(model, ctx, theta, cand, frames, rank_tol) -> Identifiability:
    """The structural identifiability of a zone (`identifiability`, the gauge `first` =
    `frames`): at the nominal robot in the measuring frames of `theta` (P,), its base frame
    and tool offset. At a zero tool offset the TCP may lie on the last joint's axis, where
    the second-to-last joint's da and dalpha move nothing; held there, the offset of a
    reflector 290 mm off the flange carried them and a new reflector (``register --tool``)
    missed by what they are."""
    at = torch.where(frames.to(theta.device), theta, model.zeros().to(theta))
    return identifiability(model.jacobian(at, ctx), model.param_names(), cand, rank_tol, first=frames)


def _identify(model, ctx, data: PoseIntervals, structural: Identifiability, x0, mu: float, rank_tol: float,
              max_iter: int) -> FitResult:
    """One zone: `fit` on the interval centers, then the interval radii |S| e_r (module doc)."""
    res = fit(model, ctx, data.center.to(x0), theta0=x0, free=structural.free, register=False, prior=False,
              damping=mu, rank_tol=rank_tol, max_iter=max_iter)
    # the structural analysis (nominal robot, x0's frames) is the zone's report; whatever fit held beyond it at theta0 is added
    report = structural if not res.report.held else \
        dataclasses.replace(res.report, held=structural.held + res.report.held)
    J = model.jacobian(res.theta, ctx).reshape(3 * len(data), -1)
    scale = model.jacobian(x0, ctx).reshape(3 * len(data), -1).norm(dim=0)  # D: column norms at theta0
    S = solution_map(J, report.free, mu, scale=scale)  # (P, 3m)
    radius = S.abs() @ data.radius.to(x0).reshape(-1)
    return dataclasses.replace(res, report=report, radius=radius)


def identify_intervals(model: CalibrationModel, data: PoseIntervals, ctx: Context | None = None,
                       **kwargs) -> FitResult:
    """Interval identification of one zone (see `identify_zones` for the arguments)."""
    item = data if ctx is None else (ctx, data)
    return identify_zones(model, [item], **kwargs)[0]
