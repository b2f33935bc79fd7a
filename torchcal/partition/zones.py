"""Hierarchical workspace partition by fuzzy c-means (docs/paper.md section 4).

Two levels of FCM (`torchcal.partition.fcm`, m = 2 by default):

1. **Levels** on R_set alone (1-D). Levels are ordered by their FCM center R_set,
   highest first: level 1 is the most reliable. Each point goes to the level of largest
   membership.
2. **Zones** inside each level, on 4 features per point, standardised per level:

       f = [(x - mean_x)/std_x, (y - mean_y)/std_y, (z - mean_z)/std_z,
            w * (R_set - mean_R)/std_R]

   means and standard deviations over that level's points (a std of 0 is replaced by 1,
   so a constant feature drops out). Position is standardised per level so that the
   three axes weigh the same whatever the level's extent; R_set is standardised the same
   way and scaled by `r_weight` w (default 1: reliability weighs as much as one spatial
   axis, so points in a zone are "close in space and similar in reliability", as the
   paper asks; w = 0 splits on position only). Each point goes to the zone of largest
   membership within its level.

Sub-zone counts per level are fixed (e.g. the paper's [3, 2, 3, 2]; 1 means "do not
split this level") or "auto": per level the c in `zone_range` (default 2..3, clipped to
n_level // max(2, knn_neighbors): a larger c cannot give each zone `knn_neighbors` points) with
the lowest Xie-Beni index, among those whose zones all hold at least `knn_neighbors` (5) sweep
points (none: the level stays one zone). A fixed count needs at
least 2 sweep points per zone of its level, else it is refused; zones that end with fewer
than `knn_neighbors` points get one `ZoneSizeWarning` (the nearest-point vote that assigns
poses and targets to zones rarely picks them). `levels` may also be "auto" (c in `level_range` by
Xie-Beni). Sub-zone centers of one level closer than MIN_CENTER_SEPARATION standard units
are refused (FCM's trivial fixed point, an m too large). Zones are numbered 1..Z level by level; within a level by descending mean
R_set of their points (ties: center x). Zone and level ids are 1-based, as in the paper.

Fuzzy memberships of the hierarchy: level memberships u_L (L, N) from eq. 28 on R_set;
zone memberships u_z = u_L[level(z)] * u_sub(z), where u_sub are the eq. 28 memberships
of the point's level-standardised features to the sub-centers of level(z); they sum to 1
over all zones. (The hard labels are hierarchical, level first, so they need not be the
argmax of the product.)

Zone of a new target point (before it is measured, so without its R_set): scikit-learn's
`KNeighborsClassifier(n_neighbors=5, weights="distance")` on the sweep positions (mm,
Euclidean) and their zone labels: a distance-weighted vote of the 5 nearest sweep points;
a target on a sweep point takes that point's zone.

A `Partition` is plain data: `torchcal.io.partition_file` saves it as JSON (never pickle) with the points, labels
and centers; memberships, summaries and the k-NN classifier are rebuilt on load.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import torch

from torchcal.errors import InputError
from torchcal.partition.fcm import as_points, fcm, memberships
from torchcal.partition.validity import _check_range, choose_c

__all__ = ["Partition", "ZoneSizeWarning", "partition_workspace"]


class ZoneSizeWarning(UserWarning):
    """Zones of a partition with fewer sweep points than its k-NN vote (`knn_neighbors`)."""


@dataclass(eq=False)
class Partition:
    """A hierarchical workspace partition (see the module docstring).

    Attributes (CPU tensors, float64 unless said):
        positions: (N, 3) sweep point positions, mm.
        r_set: (N,) set reliability of each point, in [0, 1].
        labels: (N,) int64 zone id of each point, 1..Z.
        point_ids: (N,) int64 ids of the points (the sweep's `point` column).
        level_centers: (L,) R_set center of each level, descending (level 1 first).
        zone_level: (Z,) int64 level (1..L) of each zone.
        zone_centers: (Z, 4) FCM center of each zone in its level's standardised features.
        feature_mean: (L, 4) per-level means of [x mm, y mm, z mm, R_set].
        feature_std: (L, 4) per-level standard deviations (0 replaced by 1).
        m: fuzzifier used.
        r_weight: weight w of the standardised R_set feature.
        knn_neighbors: k of the k-NN zone assignment.
        options: how it was made (requested levels/zones, ranges, seed, restarts), for the record.
        made_for: the record of the robot its sweep was made for (a plain dict {name,
            fingerprint, nominal_robot}, `torchcal.io.robot_file.robot_record`), as a
            PARTITION.json holds it; None where unknown (a partition built in memory, an
            older file). `torchcal.calibrate` checks it against the model's robot.
    """

    positions: torch.Tensor
    r_set: torch.Tensor
    labels: torch.Tensor
    point_ids: torch.Tensor
    level_centers: torch.Tensor
    zone_level: torch.Tensor
    zone_centers: torch.Tensor
    feature_mean: torch.Tensor
    feature_std: torch.Tensor
    m: float = 2.0
    r_weight: float = 1.0
    knn_neighbors: int = 5
    options: dict = field(default_factory=dict)
    made_for: dict | None = None

    # ------------------------------------------------------------------ derived
    @property
    def n_levels(self) -> int:
        return int(self.level_centers.shape[0])

    @property
    def n_zones(self) -> int:
        return int(self.zone_level.shape[0])

    @property
    def point_levels(self) -> torch.Tensor:
        """(N,) int64 level (1..L) of each point."""
        return self.zone_level[self.labels - 1]

    def features(self, level: int, positions=None, r_set=None) -> torch.Tensor:
        """(M, 4) standardised features of points for `level` (1-based); default: the sweep points."""
        pos = self.positions if positions is None else positions
        r = self.r_set if r_set is None else r_set
        raw = torch.cat([pos, r[:, None]], dim=1)  # (M, 4)
        f = (raw - self.feature_mean[level - 1]) / self.feature_std[level - 1]
        f[:, 3] *= self.r_weight
        return f

    @property
    def level_memberships(self) -> torch.Tensor:
        """(L, N) eq. 28 memberships of the sweep points to the levels (on R_set)."""
        return memberships(self.r_set, self.level_centers[:, None], self.m)

    @property
    def memberships(self) -> torch.Tensor:
        """(Z, N) hierarchical zone memberships u_L[level(z)] * u_sub(z); columns sum to 1."""
        uL = self.level_memberships
        out = torch.empty(self.n_zones, self.positions.shape[0], dtype=torch.float64)
        for lev in range(1, self.n_levels + 1):
            zs = torch.nonzero(self.zone_level == lev)[:, 0]  # zone indices (0-based) of this level
            if len(zs) == 1:
                out[zs] = uL[lev - 1]
            else:
                out[zs] = uL[lev - 1] * memberships(self.features(lev), self.zone_centers[zs], self.m)
        return out

    def zone_center_mm(self) -> torch.Tensor:
        """(Z, 3) zone centers back in mm (the FCM prototypes, not the mean of the points)."""
        lev = self.zone_level - 1
        return self.zone_centers[:, :3] * self.feature_std[lev, :3] + self.feature_mean[lev, :3]

    def summary(self) -> list[dict]:
        """Per zone: zone, level, points, R_set min/mean/max, center x/y/z (mm), level center R_set."""
        ctr = self.zone_center_mm()
        rows = []
        for z in range(1, self.n_zones + 1):
            sel = self.labels == z
            r = self.r_set[sel]
            lev = int(self.zone_level[z - 1])
            rows.append({
                "zone": z, "level": lev, "points": int(sel.sum()),
                "r_set_min": float(r.min()), "r_set_mean": float(r.mean()), "r_set_max": float(r.max()),
                "center_x_mm": float(ctr[z - 1, 0]), "center_y_mm": float(ctr[z - 1, 1]),
                "center_z_mm": float(ctr[z - 1, 2]), "level_center_r_set": float(self.level_centers[lev - 1]),
            })
        return rows

    # ------------------------------------------------------------------ assignment
    def _knn(self):
        knn = getattr(self, "_knn_cache", None)
        if knn is None:
            from sklearn.neighbors import KNeighborsClassifier

            k = min(self.knn_neighbors, self.positions.shape[0])
            knn = KNeighborsClassifier(n_neighbors=k, weights="distance")
            knn.fit(self.positions.numpy(), self.labels.numpy())
            self._knn_cache = knn
        return knn

    def nearest_sweep(self, points: torch.Tensor) -> tuple[float, torch.Tensor]:
        """(spacing mm, distances (M,) mm): the median distance between neighbouring sweep
        points (needs N >= 2), and each of `points` (M, 3) mm to its nearest sweep point. The
        KD-tree of the sweep points and the spacing are built once per partition."""
        cached = getattr(self, "_sweep_tree_cache", None)
        if cached is None:
            from scipy.spatial import cKDTree

            pts = self.positions.detach().to("cpu", torch.float64).numpy()
            tree = cKDTree(pts)
            cached = (tree, float(torch.as_tensor(tree.query(pts, k=2)[0][:, 1]).median()))
            self._sweep_tree_cache = cached
        tree, spacing = cached
        return spacing, torch.as_tensor(tree.query(points.detach().to("cpu", torch.float64).numpy(), k=1)[0])

    def assign(self, points) -> torch.Tensor:
        """Zone ids (M,) int64 of target positions `points` (M, 3) or (3,) mm, not yet measured.

        Distance-weighted vote of the `knn_neighbors` nearest sweep points (Euclidean, mm).
        """
        pts = as_points(points, "points")
        if pts.shape[1] == 1 and pts.shape[0] == 3:
            pts = pts.T  # a single (3,) point
        if pts.shape[1] != 3:
            raise InputError(f"points: expected shape (M, 3) positions in mm, got {tuple(pts.shape)}")
        pred = self._knn().predict(pts.detach().cpu().to(torch.float64).numpy())
        return torch.as_tensor(pred, dtype=torch.int64)

    def validate(self, where: str) -> None:
        """Raise InputError (naming `where`) unless the fields are consistent."""
        N = self.positions.shape[0]
        L, Z = self.n_levels, self.n_zones
        if not (self.r_set.shape == self.labels.shape == self.point_ids.shape == (N,)) or N == 0:
            raise InputError(f"{where}: points have inconsistent lengths; expected N x, y, z, r_set, zone, point")
        if L < 1 or Z < L:
            raise InputError(f"{where}: expected at least one level and one zone per level, got {L} levels, {Z} zones")
        if set(self.zone_level.tolist()) != set(range(1, L + 1)):
            raise InputError(f"{where}: zone levels {sorted(set(self.zone_level.tolist()))} do not cover levels 1..{L}")
        if int(self.labels.min()) < 1 or int(self.labels.max()) > Z:
            raise InputError(f"{where}: point zones must be in 1..{Z}")
        if self.knn_neighbors < 1 or not self.m > 1:
            raise InputError(f"{where}: expected knn_neighbors >= 1 and m > 1")


# ---------------------------------------------------------------------- building

#: two FCM sub-zone centers of one level closer than this (in the level's standard deviations)
#: are one center: FCM's trivial fixed point (m too large); honest sweeps with m = 2 give 1.3 or more
MIN_CENTER_SEPARATION = 0.05


def _as_positions_r(positions, r_set):
    pos = as_points(positions, "positions")
    if pos.shape[1] != 3:
        raise InputError(f"positions: expected shape (N, 3) in mm, got {tuple(pos.shape)}")
    r = as_points(r_set, "r_set")
    if r.shape[1] != 1 or r.shape[0] != pos.shape[0]:
        raise InputError(f"r_set: expected shape ({pos.shape[0]},) to match positions, got {tuple(r.shape)}")
    if r.device != pos.device:
        raise InputError(f"r_set: on device {r.device}, but positions are on {pos.device}; expected the same device")
    return pos.to(torch.float64), r[:, 0].to(torch.float64)


def _parse_zones(zones, n_levels):
    if isinstance(zones, str):
        if zones != "auto":
            raise InputError(f"zones: expected 'auto' or a list of sub-zone counts, got {zones!r}")
        return None
    try:
        ks = [int(k) for k in zones]
    except (TypeError, ValueError):
        raise InputError(f"zones: expected 'auto' or a list of integers, got {zones!r}") from None
    if any(k != z for k, z in zip(ks, zones)) or any(k < 1 for k in ks):
        raise InputError(f"zones: expected integers >= 1, got {list(zones)!r}")
    if len(ks) != n_levels:
        raise InputError(f"zones: {len(ks)} sub-zone counts {ks} for {n_levels} levels; expected one count per level")
    return ks


def _check_distinct_centers(centers: torch.Tensor, f: torch.Tensor, lev: int, m: float) -> None:
    """InputError when two FCM sub-zone centers (k, 4) of level `lev` lie closer than
    MIN_CENTER_SEPARATION standard units apart (f (n_l, 4): the level's standardised
    features): FCM fell to its trivial fixed point (every membership 1/k, each center the
    level's mean), where the hard split is decided by rounding, not by the points."""
    d = torch.cdist(centers, centers).fill_diagonal_(math.inf)
    spread = float(f.std(dim=0, correction=0).max()) if f.shape[0] > 1 else 1.0
    gap = float(d.min()) / max(spread, 1e-300)
    if gap < MIN_CENTER_SEPARATION:
        raise InputError(f"zones: the FCM sub-zones of level {lev} share one center ({gap:.2g} standard "
                         f"deviations apart, below {MIN_CENTER_SEPARATION:g}): with fuzzifier m = {m:g} every "
                         f"point's memberships are equal and the split is arbitrary; expected a smaller m "
                         f"(default 2) or fewer sub-zones")


def partition_workspace(positions, r_set, levels=4, zones="auto", *, m: float = 2.0, r_weight: float = 1.0,
                        seed: int = 0, restarts: int = 5, eps: float = 1e-6, max_iter: int = 300,
                        level_range=(2, 6), zone_range=(2, 3), knn_neighbors: int = 5,
                        point_ids=None) -> Partition:
    """Hierarchical FCM partition of sweep points (see the module docstring).

    Args:
        positions: (N, 3) sweep point positions, mm (any device; FCM runs there).
        r_set: (N,) set reliability per point.
        levels: number of levels L >= 2, or "auto" (Xie-Beni minimum in `level_range`).
        zones: sub-zone counts per level, a sequence of L integers >= 1 (paper: [3, 2, 3, 2]),
            or "auto" (per level, Xie-Beni minimum in `zone_range`, clipped to
            n_level // max(2, knn_neighbors) and to the number of distinct points, among the c whose zones all
            hold knn_neighbors points; a level where that leaves no c in the
            range stays one zone).
        level_range, zone_range: inclusive (low, high) ranges for "auto" (defaults (2, 6)
            and (2, 3), the paper's counts; on evenly spread points Xie-Beni tends to fall
            as c grows, so the upper end of the range bounds the answer).
        m: fuzzifier (default 2).
        r_weight: weight w of the standardised R_set feature in the second level (default 1).
        seed, restarts, eps, max_iter: passed to `fcm` (each FCM keeps the best of `restarts`).
        knn_neighbors: k of `Partition.assign` (default 5).
        point_ids: (N,) integer ids of the points (default 0..N-1).

    Returns:
        Partition (CPU tensors).

    Raises:
        InputError: bad shapes, NaN/inf, R_set with fewer distinct values than levels, a level
            with fewer than 2 points per requested zone, or an FCM that leaves a level or zone
            empty. ZoneSizeWarning: zones of fewer than knn_neighbors points.
    """
    pos, r = _as_positions_r(positions, r_set)
    N = pos.shape[0]
    if not isinstance(r_weight, (int, float)) or not math.isfinite(r_weight) or r_weight < 0:
        raise InputError(f"r_weight: expected a finite weight >= 0, got {r_weight!r}")
    if isinstance(knn_neighbors, bool) or not isinstance(knn_neighbors, int) or knn_neighbors < 1:
        raise InputError(f"knn_neighbors: expected an integer >= 1, got {knn_neighbors!r}")
    if point_ids is None:
        ids = torch.arange(N, dtype=torch.int64)
    else:
        ids = torch.as_tensor(np.asarray(point_ids), dtype=torch.int64).reshape(-1)
        if ids.shape[0] != N:
            raise InputError(f"point_ids: expected {N} ids, got {ids.shape[0]}")
    level_range = _check_range(level_range, "level_range")
    zone_range = _check_range(zone_range, "zone_range")
    n_distinct = int(torch.unique(r).numel())
    if n_distinct < 2:
        raise InputError(f"r_set: all {N} values are equal ({float(r[0])}); no split into levels is possible")
    kw = dict(m=m, eps=eps, max_iter=max_iter, seed=seed, restarts=restarts)

    # level 1: FCM on R_set
    if isinstance(levels, str):
        if levels != "auto":
            raise InputError(f"levels: expected an integer >= 2 or 'auto', got {levels!r}")
        if n_distinct < level_range[0]:
            raise InputError(f"r_set: only {n_distinct} distinct values among {N} points; levels='auto' tries "
                             f"{level_range[0]}..{level_range[1]} levels (expected a smaller level_range)")
        L, res, _ = choose_c(r, (level_range[0], min(level_range[1], n_distinct)), **kw)
    else:
        if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 2:
            raise InputError(f"levels: expected an integer >= 2 or 'auto', got {levels!r}")
        L = int(levels)
        if n_distinct < L:
            raise InputError(f"r_set: only {n_distinct} distinct values among {N} points; cannot form {L} levels "
                             f"(expected levels <= {n_distinct})")
        res = fcm(r, L, **kw)
    ks = _parse_zones(zones, L)
    order = torch.argsort(res.centers[:, 0], descending=True)  # most reliable first
    level_centers = res.centers[order, 0].cpu()
    rank = torch.empty_like(order)
    rank[order] = torch.arange(L, device=order.device)
    point_level = (rank[res.memberships.argmax(dim=0)] + 1).cpu()  # (N,) 1..L
    pos_c, r_c = pos.cpu(), r.cpu()

    labels = torch.empty(N, dtype=torch.int64)
    zone_level, zone_centers, f_mean, f_std = [], [], [], []
    for lev in range(1, L + 1):
        idx = torch.nonzero(point_level == lev)[:, 0]
        n_l = idx.numel()
        if n_l == 0:
            raise InputError(f"levels: level {lev} of {L} got no points (R_set centers {level_centers.tolist()}); "
                             "expected fewer levels")
        raw = torch.cat([pos_c[idx], r_c[idx, None]], dim=1)  # (n_l, 4)
        mean = raw.mean(dim=0)
        std = raw.std(dim=0, correction=0) if n_l > 1 else torch.zeros(4, dtype=torch.float64)
        std = torch.where(std > 1e-12 * (1 + mean.abs()), std, torch.ones_like(std))
        f = (raw - mean) / std
        f[:, 3] *= r_weight
        f_mean.append(mean)
        f_std.append(std)
        if ks is None:  # auto: c in zone_range, below the number of points and of distinct points;
            # c zones of knn_neighbors points each need c * knn_neighbors points: a larger c is never chosen
            hi = min(zone_range[1], n_l // max(2, knn_neighbors), int(torch.unique(f, dim=0).shape[0]))
            k = None if hi >= zone_range[0] else 1
        else:
            k = ks[lev - 1]
            if k > 1 and 2 * k > n_l:
                raise InputError(f"zones: level {lev} has {n_l} points, too few for {k} sub-zones: a zone needs "
                                 f"at least 2 sweep points on average, so at most {max(1, n_l // 2)} sub-zone(s) "
                                 f"here (expected fewer zones, or a denser sweep)")
            if k > 1 and bool((f == f[0]).all()):
                raise InputError(f"zones: the {n_l} points of level {lev} share one position and R_set; "
                                 f"no split into {k} sub-zones is possible")
        sub = None
        if k is None:  # a c whose FCM leaves a zone below knn_neighbors points is not chosen; none: one zone
            k, sub, _ = choose_c(f.to(pos.device), (zone_range[0], hi), min_size=knn_neighbors, **kw)
            k = k or 1
        elif k > 1:
            sub = fcm(f.to(pos.device), k, **kw)
        if k > 1:
            _check_distinct_centers(sub.centers.cpu(), f, lev, m)
        if k == 1:
            sub_labels = torch.zeros(n_l, dtype=torch.int64)
            centers = torch.zeros(1, 4, dtype=torch.float64)
        else:
            centers = sub.centers.cpu()
            sub_labels = sub.memberships.argmax(dim=0).cpu()
        # order sub-zones: descending mean R_set of their points, then center x
        keys = []
        for j in range(k):
            sel = sub_labels == j
            if not bool(sel.any()):
                raise InputError(f"zones: FCM left sub-zone {j + 1} of level {lev} empty; expected fewer sub-zones")
            keys.append((-float(r_c[idx][sel].mean()), float(centers[j, 0]), j))
        perm = [j for _, _, j in sorted(keys)]
        base = len(zone_level)
        new_id = torch.empty(k, dtype=torch.int64)
        new_id[perm] = torch.arange(k) + base + 1
        labels[idx] = new_id[sub_labels]
        zone_level += [lev] * k
        zone_centers.append(centers[perm])

    sizes = torch.bincount(labels, minlength=len(zone_level) + 1)[1:]
    small = (sizes < knn_neighbors).nonzero().flatten()
    if small.numel():
        z = [f"{int(i) + 1} ({int(sizes[i])})" for i in small[:5]]
        more = f" and {small.numel() - 5} more" if small.numel() > 5 else ""
        warnings.warn(ZoneSizeWarning(
            f"zones: {small.numel()} of {len(zone_level)} zones hold fewer than {knn_neighbors} sweep points "
            f"(zone (points): {', '.join(z)}{more}): the nearest-point vote that assigns poses and targets to "
            f"zones rarely picks such a zone, and its calibration rests on few poses; fewer zones, or a denser "
            f"sweep"), stacklevel=2)

    options = {"levels": levels if isinstance(levels, str) else int(levels),
               "zones": zones if isinstance(zones, str) else [int(k) for k in zones],
               "level_range": [int(v) for v in level_range], "zone_range": [int(v) for v in zone_range],
               "seed": int(seed), "restarts": int(restarts), "eps": float(eps), "max_iter": int(max_iter)}
    return Partition(
        positions=pos_c.contiguous(), r_set=r_c.contiguous(), labels=labels, point_ids=ids,
        level_centers=level_centers, zone_level=torch.tensor(zone_level, dtype=torch.int64),
        zone_centers=torch.cat(zone_centers), feature_mean=torch.stack(f_mean), feature_std=torch.stack(f_std),
        m=float(m), r_weight=float(r_weight), knn_neighbors=int(knn_neighbors), options=options,
    )
