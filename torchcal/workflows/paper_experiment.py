"""The paper's pipeline (docs/paper.md sections 3-6) as a fair experiment on a simulated KR 1000 Titan.

`run_demo(DemoConfig(), seeds=K)` is what `torchcal demo --seeds K` runs; `run_pipeline(cfg)`
is one seed. Its configuration: `torchcal.workflows.paper_config`; the figures and JSON
of its results: `torchcal.workflows.paper_report`; `torchcal.cli._report` prints them.

1. **The robot** (`build_virtual_robot`): a `VirtualRobot` whose errors are *not all inside
   any fitted model* (sizes and where they come from: docs/demo.md):

   - MD-H deviations, uniform in +-`geometric_scale` x (0.5 mm, 0.02 deg);
   - the measurement (laser tracker) frame: `base_offset_mm`, `base_tilt_deg` (every
     method fits it: ``base_frame`` is in every fitted model);
   - joint compliance ``joint_compliance:2,3`` under a payload drawn per pose from 0 to
     the rated 1000 kg, `compliance_mm` RMS at the TCP;
   - a gear (transmission) error ``gear_periodic:2,3``, `gear_mm` RMS at the TCP;
   - joint clearance on every joint (docs/paper.md Table 2 sizes), `clearance_random` of
     it random per move (the simulator's default, 0.5), the rest pushed by the load;
   - measurement noise `noise_mm` per axis.

   `truth_effects` lists them; set it to ``("base_frame",)`` (and `clearance_random` to
   1.0) for the control experiment without unmodelled position-dependent error.
2. **Sweep and partition** (Table 3, FCM into 3/2/3/2 = 10 zones), as the paper.
3. **Calibration poses**: `points_per_zone` (10, the paper's) per zone, `repeats` moves each;
   `points_per_zone_more` per zone for the "more poses" variant.
4. **Methods** (`METHODS`), all fitted to the same calibration measurements:

   - ``paper_partitioned``: geometric + base_frame per zone, eq. 29 damped least squares
     with mu = `paper_mu` (1e-3, relative to the column norms) from nominal;
     variants ``paper_partitioned_gcv`` (mu per zone by GCV) and ``paper_partitioned_more``
     (`points_per_zone_more` poses per zone);
   - ``global_geometric``: geometric + base_frame fitted once to all calibration poses;
   - ``discovered_global``: `torchcal.diagnosis.diagnose.discover` on the calibration
     measurements (starting from base_frame, at most `discover_rounds` effects added),
     that model fitted once; ``discover_rounds = 0`` skips discovery (then it equals
     global_geometric);
   - ``discovered_partitioned``: the discovered global fit plus a per-zone correction of
     the geometric and base-frame parameters, damped towards the global fit (mu =
     `paper_mu`), the effect parameters held at the global values.
5. **Test**: `test_per_zone` fresh poses per zone (new seed, assigned to zones before
   measuring, never used for fitting), moved to `repeats` times before compensation and
   with each method's compensated commands, in one fresh measurement session shared by
   every method. Each method's compensation is checked (converged, within the joint
   limits); failures are counted and reported, their moves stay in the figures.
6. **Figures** per method: test RMS, the paper's six reductions
   ``100 * (1 - |mean bound after| / |mean bound before|)`` per axis and bound, and over
   seeds the mean and the 95 % confidence interval (Student t). Partitioned vs global
   (``paper_partitioned`` - ``global_geometric`` test RMS) is a paired comparison: over
   seeds when K >= 2, over test points (per-point RMS) when K = 1; "beats" only when the
   two-sided paired t-test gives p < 0.05.

Everything is seeded: seed s of a K-seed run is ``cfg.seed + s``. Units: mm and degrees in
the config and the outputs, rad inside.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import torch

from torchcal import threads
from torchcal.reliability import rset as reliability
from torchcal.calibration.compensate import compensate
from torchcal.errors import InputError
from torchcal.calibration.intervals import identify_zones, pose_intervals
from torchcal.calibration.model import CalibrationModel
from torchcal.diagnosis.diagnose import discover
from torchcal.partition.zones import partition_workspace
from torchcal.io.robot_file import robot as make_robot
from torchcal.simulation.virtual_robot import VirtualRobot
from torchcal.reliability.sweep import SweepResult, sweep
from torchcal.robots.workspace import sample_workspace
from torchcal.workflows.paper_config import AXES, METHODS, DemoConfig
from torchcal.workflows.paper_report import DemoRun, reduction_percent


# ------------------------------------------------------------------ steps

def build_virtual_robot(cfg: DemoConfig, seed: int | None = None) -> VirtualRobot:
    """The simulated "real" robot of the demo (module doc, step 1)."""
    r = make_robot(cfg.robot)
    base = torch.tensor([*cfg.base_offset_mm, *(math.radians(a) for a in cfg.base_tilt_deg)],
                        dtype=torch.float64)
    sizes = {"joint_compliance": cfg.compliance_mm, "gear_periodic": cfg.gear_mm,
             "joint_clearance": cfg.clearance_mm}
    return VirtualRobot(r, effects=list(cfg.truth_effects), seed=cfg.seed if seed is None else seed,
                        geometric_scale=cfg.geometric_scale, effect_mm=sizes,
                        clearance_random=cfg.clearance_random, values={"base_frame": base})


def error_intervals(meas, targets: torch.Tensor):
    """Per pose the per-axis interval of measured - target.

    meas: Measurements with pose ids 0..m-1; targets (m, 3) mm indexed by pose id.
    Returns (lower (m, 3), upper (m, 3)) mm in pose-id order.
    """
    pi = pose_intervals(meas)
    order = torch.argsort(pi.pose)
    t = targets[pi.pose[order]]
    return pi.lower[order] - t, pi.upper[order] - t


def _max_distance(meas, targets: torch.Tensor) -> torch.Tensor:
    """(m,) largest |measured - target| per pose id, mm."""
    d = (meas.xyz - targets[meas.pose]).norm(dim=-1)
    return torch.zeros(targets.shape[0], dtype=d.dtype).scatter_reduce(0, meas.pose, d, "amax")


def measured_sweep(vr: VirtualRobot, q: torch.Tensor, repeats: int, allowed_mm: float,
                   noise_mm: float, seed: int) -> SweepResult:
    """Repeated moves to each workspace point q (N, n) rad: per-axis error intervals,
    the distance interval ``[0, max_k |e_k|]`` (as the paper's Table 3), eta and R_set
    against ``[0, allowed_mm]``. Errors are measured - nominal target, mm."""
    target = vr.robot.fk(q)
    meas = vr.measure(q, repeats=repeats, noise_mm=noise_mm, seed=seed)
    lo, hi = error_intervals(meas, target)
    d_hi = _max_distance(meas, target)
    d_lo = torch.zeros_like(d_hi)
    rs = reliability.r_set((0.0, allowed_mm), (d_lo, d_hi))
    et = reliability.eta((None, allowed_mm), (d_lo, d_hi))
    return SweepResult(q=q, positions=target, err_lower=lo, err_upper=hi, dist_lower=d_lo,
                       dist_upper=d_hi, eta=et, r_set=rs, allowed_mm=float(allowed_mm), n_samples=repeats)


def sample_in_zones(robot, partition, per_zone: int, seed: int, pool: int = 2000,
                    max_rounds: int = 8) -> tuple[torch.Tensor, torch.Tensor]:
    """`per_zone` workspace configurations per zone.

    Latin-hypercube pools (`sample_workspace`, seeds derived from `seed`) are assigned by
    `partition.assign` on their nominal positions; the first `per_zone` of each zone are
    kept. Returns q (Z * per_zone, n) rad grouped zone by zone, zone (Z * per_zone,)
    0-based. Raises InputError if a zone stays short after `max_rounds` pools.
    """
    Z = partition.n_zones
    picked: list[list[torch.Tensor]] = [[] for _ in range(Z)]
    for k in range(max_rounds):
        q = sample_workspace(robot, pool * (2 ** k), seed=seed + 7919 * k)
        z = partition.assign(robot.fk(q)) - 1  # 0-based
        for zi in range(Z):
            need = per_zone - sum(len(t) for t in picked[zi])
            if need > 0:
                picked[zi].append(q[z == zi][:need])
        if all(sum(len(t) for t in p) >= per_zone for p in picked):
            break
    short = [zi + 1 for zi in range(Z) if sum(len(t) for t in picked[zi]) < per_zone]
    if short:
        raise InputError(f"could not draw {per_zone} workspace points inside zone(s) {short}")
    return torch.cat([torch.cat(p) for p in picked]), torch.arange(Z).repeat_interleave(per_zone)


def make_partition(sweep: SweepResult, zones_per_level, seed: int, tries: int = 3):
    """`partition_workspace` on the sweep with the requested sub-zone counts.

    When FCM leaves a level with too few points for its zones, the FCM seed is advanced
    (up to `tries` seeds: the result stays deterministic); if that does not help, each
    level's count is clipped to half its points (at least 1) and the partition says so in
    ``options["zones"]``.
    """
    import warnings

    from torchcal.partition.zones import ZoneSizeWarning

    L = len(zones_per_level)
    ks = [int(z) for z in zones_per_level]
    with warnings.catch_warnings():  # the paper's small zones: the result's "zones" list their sweep points
        warnings.simplefilter("ignore", ZoneSizeWarning)
        for k in range(tries):
            try:
                return partition_workspace(sweep.positions, sweep.r_set, levels=L, zones=ks, seed=seed + k)
            except InputError:
                pass
        levels = partition_workspace(sweep.positions, sweep.r_set, levels=L, zones=[1] * L, seed=seed)
        sizes = [int((levels.point_levels == lev).sum()) for lev in range(1, L + 1)]
        clipped = [max(1, min(k, n // 2)) for k, n in zip(ks, sizes)]
        return partition_workspace(sweep.positions, sweep.r_set, levels=L, zones=clipped, seed=seed)


def r_set_table(lo: torch.Tensor, hi: torch.Tensor, dist_hi: torch.Tensor, allowed_axis: float,
                allowed_dist: float) -> torch.Tensor:
    """(M, 4) R_set per axis (intervals [lo, hi] (M, 3) against +-allowed_axis) and of the
    distance [0, dist_hi] against [0, allowed_dist]; mm."""
    axis = reliability.r_set((-allowed_axis, allowed_axis), (lo, hi))  # (M, 3)
    dist = reliability.r_set((0.0, allowed_dist), (torch.zeros_like(dist_hi), dist_hi))
    return torch.cat([axis, dist[:, None]], dim=1)


# ------------------------------------------------------------------ results

@dataclass(eq=False)
class MoveErrors:
    """Moves to the test points with one set of commands.

    Attributes:
        q: (M, n) rad commands. lower, upper: (M, 3) mm error intervals over the moves.
        dist_upper: (M,) mm largest distance error. r_set: (M, 4) x, y, z, distance.
        rms_mm: RMS distance error over all moves. predicted_residual_mm: (M, 3) the
        calibrated model's own residual at q (None before compensation).
        point_rms_mm: (M,) RMS distance error per point over its moves.
    """

    q: torch.Tensor
    lower: torch.Tensor
    upper: torch.Tensor
    dist_upper: torch.Tensor
    r_set: torch.Tensor
    rms_mm: float
    predicted_residual_mm: torch.Tensor | None = None
    point_rms_mm: torch.Tensor | None = None

    @property
    def max_abs_mm(self) -> float:
        return float(torch.maximum(self.lower.abs(), self.upper.abs()).max())

    def interval(self, i: int) -> dict:
        return {ax: [float(self.lower[i, k]), float(self.upper[i, k])] for k, ax in enumerate(AXES)}

    def r_set_dict(self, i: int) -> dict:
        return dict(zip((*AXES, "distance"), map(float, self.r_set[i])))


@dataclass(eq=False)
class PipelineResult:
    """One seed of the demo.

    fits: {method: [interval FitResult per zone]} (one element for the global methods);
    models: {method: CalibrationModel}; comps: {method: Compensation};
    after: {method: MoveErrors}; cal_q: {"paper": (P, n), "more": (P', n)} rad calibration
    poses; zone_extent: per zone the RMS and largest distance of its sweep points from
    their centroid, mm.
    """

    config: DemoConfig
    seed: int
    seconds: float
    sweep: SweepResult
    partition: object
    fits: dict
    models: dict
    test_q: torch.Tensor
    test_zone: torch.Tensor  # (M,) 0-based
    test_targets: torch.Tensor
    before: MoveErrors
    after: dict
    comps: dict
    cal_q: dict
    truth_effects: list
    timings: dict = field(default_factory=dict)

    @property
    def n_zones(self) -> int:
        return int(self.partition.n_zones)

    @property
    def zone_level(self) -> list[int]:
        """1-based level of each zone."""
        return [int(v) for v in self.partition.zone_level]

    def reductions(self, which: str = "paper_partitioned", absolute: bool = False) -> dict:
        ev = self.after[which]
        return reduction_percent(self.before.lower, self.before.upper, ev.lower, ev.upper, absolute)

    def compensation(self, which: str) -> dict:
        """Compensation check of one method over the test targets (counts)."""
        c = self.comps[which]
        ok = c.converged & c.within_limits
        return {"targets": int(ok.numel()), "converged": int(c.converged.sum()),
                "within_limits": int(c.within_limits.sum()), "failed": int((~ok).sum())}

    def targets_met(self, which: str = "paper_partitioned") -> dict:
        """Every test point within +-allowed_axis_mm and R_set = 1 after compensation."""
        ev = self.after[which]
        lim = self.config.allowed_axis_mm
        within = bool((ev.lower >= -lim).all() and (ev.upper <= lim).all())
        rset1 = bool((ev.r_set >= 1.0).all())
        return {"all_within_allowed_axis": within, "all_r_set_1": rset1, "all": within and rset1}

    def zone_extent(self) -> list[dict]:
        """Per zone: sweep points, RMS and largest distance from their centroid (mm)."""
        out = []
        pos, lab = self.sweep.positions, self.partition.labels
        for z in range(1, self.n_zones + 1):
            p = pos[lab == z]
            d = (p - p.mean(0)).norm(dim=-1) if len(p) else torch.zeros(1, dtype=pos.dtype)
            out.append({"zone": z, "sweep_points": int(len(p)), "rms_radius_mm": float(d.pow(2).mean().sqrt()),
                        "max_radius_mm": float(d.max())})
        return out

    def workspace_rms_radius_mm(self) -> float:
        p = self.sweep.positions
        return float((p - p.mean(0)).norm(dim=-1).pow(2).mean().sqrt())

    def summary(self, which: str) -> dict:
        ev = self.after[which]
        return {"test_rms_mm": ev.rms_mm, "max_abs_error_mm": ev.max_abs_mm,
                "reduction_percent": self.reductions(which),
                "robust_reduction_percent": self.reductions(which, absolute=True),
                "targets_met": self.targets_met(which), "compensation": self.compensation(which),
                "effects": self.models[which].specs(), "description": METHODS[which][1],
                "damping": [f.damping for f in self.fits[which]]}

    def point_rms(self, which: str | None) -> torch.Tensor:
        """(M,) RMS distance error per test point over its moves (None: before), mm."""
        ev = self.before if which is None else self.after[which]
        return ev.point_rms_mm


# ------------------------------------------------------------------ the pipeline

def _evaluate(vr, q, targets, cfg, seed, predicted=None) -> MoveErrors:
    meas = vr.measure(q, repeats=cfg.repeats, noise_mm=cfg.noise_mm, seed=seed)
    lo, hi = error_intervals(meas, targets)
    d_hi = _max_distance(meas, targets)
    rs = r_set_table(lo, hi, d_hi, cfg.allowed_axis_mm, cfg.allowed_distance_mm)
    d2 = (meas.xyz - targets[meas.pose]).pow(2).sum(-1)
    per = torch.zeros(targets.shape[0], dtype=d2.dtype).index_add_(0, meas.pose, d2)
    cnt = torch.zeros_like(per).index_add_(0, meas.pose, torch.ones_like(d2))
    return MoveErrors(q, lo, hi, d_hi, rs, float(d2.mean().sqrt()), predicted, (per / cnt).sqrt())


def _zones_of(data, z_of_pose, n_zones):
    return [data.subset((z_of_pose == z).nonzero().flatten()) for z in range(n_zones)]


def _intervals(meas):
    data = pose_intervals(meas)
    return data.subset(torch.argsort(data.pose))  # pose id order = q order


# Share of one seed's time each step takes (default DemoConfig on a CPU, measured: sweep
# 0.17 s, partition 0.03 s, calibrate 1.27 s, discover + its fit 7.9 s, compensate and test
# 0.33 s of 9.7 s): progress reports the work done, not the steps started.
STEP_SHARE = {"sweep": 0.02, "partition": 0.01, "calibrate": 0.13, "discover": 0.81, "test": 0.03}


def step_shares(cfg: DemoConfig) -> dict:
    """{step: share of one seed's time} summing to 1 (no discovery: its share goes)."""
    w = dict(STEP_SHARE)
    if cfg.discover_rounds == 0:
        w["discover"] = 0.02  # the discovered model's fit alone
    total = sum(w.values())
    return {k: v / total for k, v in w.items()}


def run_pipeline(cfg: DemoConfig | None = None, progress=None, device=None) -> PipelineResult:
    """One seed (``cfg.seed``) of the experiment (module doc); returns its `PipelineResult`.

    device: where the workspace sweep (the batched kernel, N x M perturbed FK) runs
    (default the CPU); the fits of 100-pose sessions stay on the CPU, where they are small.

    progress: optional callable(step_name: str, done: float), called as each step starts
    with the share of this seed's work done before it (`step_shares`), and once more as
    ("done", 1.0) when the seed is finished.
    """
    cfg = DemoConfig() if cfg is None else cfg
    cfg.check()
    shares, done = step_shares(cfg), [0.0]

    def say(step):
        if step == "done":
            done[0] = 1.0
        if progress is not None:
            progress(step, done[0])
        if step != "done":
            done[0] += shares[step]
    t0 = time.perf_counter()
    timings: dict = {}
    tick = [t0]

    def lap(name):
        now = time.perf_counter()
        timings[name] = now - tick[0]
        tick[0] = now

    vr = build_virtual_robot(cfg)
    r, seed = vr.robot, cfg.seed
    # every measurement session has its own seed (else they would share their randomness)
    s_sweep, s_cal, s_meas, s_test, s_before, s_after, s_more, s_more_meas = (seed * 1009 + k for k in range(1, 9))
    say("sweep")
    q_sweep = sample_workspace(r, cfg.n_sweep, seed=seed)
    if cfg.sweep_source == "model":
        sw = sweep(r, q_sweep, n_samples=cfg.sweep_samples, allowed_mm=cfg.allowed_distance_mm, seed=seed,
                   device=device).to("cpu")
    else:
        sw = measured_sweep(vr, q_sweep, cfg.repeats, cfg.allowed_distance_mm, cfg.noise_mm, seed=s_sweep)
    lap("sweep")
    say("partition")
    part = make_partition(sw, cfg.zones_per_level, seed)
    Z = part.n_zones
    lap("partition")
    say("calibrate")
    q_cal, z_cal = sample_in_zones(r, part, cfg.points_per_zone, s_cal)
    meas = vr.measure(q_cal, repeats=cfg.repeats, noise_mm=cfg.noise_mm, seed=s_meas)
    data = _intervals(meas)
    zones = _zones_of(data, z_cal, Z)
    q_more, z_more = sample_in_zones(r, part, cfg.points_per_zone_more, s_more)
    zones_more = _zones_of(_intervals(vr.measure(q_more, repeats=cfg.repeats, noise_mm=cfg.noise_mm,
                                                 seed=s_more_meas)), z_more, Z)
    geo = CalibrationModel(r, ["base_frame"])
    tol = cfg.rank_tol
    fits = {"global_geometric": identify_zones(geo, [data], rank_tol=tol),
            "paper_partitioned": identify_zones(geo, zones, rank_tol=tol, damping=cfg.paper_mu),
            "paper_partitioned_gcv": identify_zones(geo, zones, rank_tol=tol, damping="gcv"),
            "paper_partitioned_more": identify_zones(geo, zones_more, rank_tol=tol, damping=cfg.paper_mu)}
    lap("calibrate_geometric")
    say("discover")
    if cfg.discover_rounds > 0:
        found = discover(r, meas, ["base_frame"], seed=seed, max_rounds=cfg.discover_rounds,
                         report_rest=False).final_effects  # the effects only: no probe of what remains
    else:
        found = ["base_frame"]
    disc = CalibrationModel(r, found)
    lap("discover")
    fits["discovered_global"] = identify_zones(disc, [data], rank_tol=tol)
    free = torch.zeros(disc.n_params, dtype=torch.bool)
    free[: disc.slices[1].stop] = True  # geometric + base_frame (the first effect)
    free &= disc.default_free()
    fits["discovered_partitioned"] = identify_zones(disc, zones, free=free, rank_tol=tol, damping=cfg.paper_mu,
                                                    theta0=fits["discovered_global"][0].theta)
    lap("calibrate_discovered")
    models = {k: (disc if k.startswith("discovered") else geo) for k in METHODS}
    say("test")
    q_test, z_test = sample_in_zones(r, part, cfg.test_per_zone, s_test)  # fresh, assigned before measuring
    targets = r.fk(q_test)
    before = _evaluate(vr, q_test, targets, cfg, s_before)
    comps = {}
    for k in METHODS:
        thetas = torch.stack([f.theta for f in fits[k]])
        comps[k] = compensate(models[k], thetas, targets, q_test,
                              zone=z_test if METHODS[k][0] else torch.zeros_like(z_test))
    lap("compensate")
    # one fresh session seed for every method: the robot's random part is common to all
    after = {k: _evaluate(vr, c.q, targets, cfg, s_after, c.residual_mm) for k, c in comps.items()}
    lap("test_moves")
    say("done")
    return PipelineResult(cfg, seed, time.perf_counter() - t0, sw, part, fits, models, q_test, z_test, targets,
                          before, after, comps, {"paper": q_cal, "more": q_more},
                          [str(s) for s in vr.specs], timings)


def run_demo(cfg: DemoConfig | None = None, seeds: int = 1, progress=None, device=None,
             processes: int = 1) -> DemoRun:
    """`run_pipeline` for seeds ``cfg.seed .. cfg.seed + seeds - 1`` (sweeps on `device`).

    processes: seeds are independent; with processes > 1 (and more than one seed) they run
    on that many fresh processes of this machine, one thread each, the results the same
    as one after another (each seed's draws come from its own seeds). Progress is then
    reported per finished seed ("seed k/K: done").

    progress: optional callable(message: str, done: float): "seed k/K: STEP" as each step
    starts, with the share of the whole run's work done before it (0 .. 1; 1 once the last
    seed is finished)."""
    cfg = DemoConfig() if cfg is None else cfg
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise InputError(f"seeds: expected a positive integer, got {seeds!r}")
    t0 = time.perf_counter()
    if processes > 1 and seeds > 1:
        runs = _seeds_in_processes([replace(cfg, seed=cfg.seed + k) for k in range(seeds)],
                                   min(processes, seeds), progress, device)
        return DemoRun(cfg, runs, time.perf_counter() - t0)
    runs = []
    for k in range(seeds):
        say = (lambda step, done, k=k: progress(f"seed {k + 1}/{seeds}: {step}", (k + done) / seeds)) \
            if progress else None
        runs.append(run_pipeline(replace(cfg, seed=cfg.seed + k), progress=say, device=device))
    return DemoRun(cfg, runs, time.perf_counter() - t0)


def _one_seed(cfg: DemoConfig, device) -> bytes:
    """One seed in a worker process (torch and BLAS on one thread), pickled here: the plain
    pickle keeps tensors that carry autograd history (a fitted effect's), which the
    process pool's own pickler refuses."""
    import pickle

    threads.apply()
    return pickle.dumps(run_pipeline(cfg, device=device))


def _seeds_in_processes(cfgs: list, processes: int, progress, device) -> list:
    """`run_pipeline` of each config on `processes` spawned processes, in config order."""
    import multiprocessing
    import pickle
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # each process starts by importing torch as the command line does (its import's
    # objects frozen: no full collection scans them again, the one at exit included)
    with ProcessPoolExecutor(processes, mp_context=multiprocessing.get_context("spawn"),
                             initializer=threads.apply_importing) as pool:
        futures = {pool.submit(_one_seed, c, device): k for k, c in enumerate(cfgs)}
        runs, done = [None] * len(cfgs), 0
        for f in as_completed(futures):
            runs[futures[f]] = pickle.loads(f.result())
            done += 1
            if progress is not None:
                progress(f"seed {futures[f] + 1}/{len(cfgs)}: done", done / len(cfgs))
    return runs
