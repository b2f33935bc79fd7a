"""Joint clearance (shaft in hole), the paper's source of uncertainty, as MD-H deviations.

docs/paper.md section 6 / Table 2 (KR 1000 Titan, fits H6/h5): 12 radius variables DV1..DV12,
two per joint. We read them as the two bearing seats of each joint (DV1, DV2 -> joint 1,
DV3, DV4 -> joint 2, ..., DV11, DV12 -> joint 6), each with its maximum radial clearance
(the table's "max clearance" column, mm). The constants below are the table verbatim,
DV11's clearance 0.000 included (the OCR reads "0.000(?)"; an H6/h5 pair of those
tolerances would give 0.022, which DV12 carries).

Model (`ClearanceModel`): joint j's shaft sits in two seats a bearing length L_j apart
along the joint axis. In a clearance state each seat k holds the shaft axis at a radial
offset u_k (a 2-vector perpendicular to the axis, |u_k| <= c_k). The axis therefore

- shifts by ``t = (u_1 + u_2) / 2`` (at the mid-plane between the seats), |t| <= (c_1 + c_2) / 2;
- tilts by ``(u_2 - u_1) / L_j`` rad, at most ``(c_1 + c_2) / L_j``,

a small rigid motion of everything after joint j, relative to the link carrying the hole.
Sampling (`sample_states`): ``mode="contact"`` (default) puts each shaft against its hole
wall, ``|u_k| = c_k`` in a uniformly random direction (a loaded shaft leans on its seat,
and the extremes of every error lie there); ``mode="disc"`` draws u_k uniformly in the
disc ``|u_k| <= c_k``.

Mapping to MD-H deviations (`deviation_map`, first order, docs/paper.md eq. 14): joint j's axis
is the z axis of frame j-1, the end frame of link j-1. The axis motion, expressed in that
frame with its pivot at the frame's origin (on the axis), is produced by link j-1's
deviations with dtheta_{j-1} = 0: the shift along x -> da_{j-1}, along y -> dd_{j-1}
(z_{j-2} is +-y_{j-1} where alpha_{j-1} = -+90 deg), the tilt about x -> dalpha_{j-1},
about y -> dbeta_{j-1}; the by-products along / about z_{j-1} are cancelled by dd_j and
dtheta_j (they commute with joint j's rotation). Where alpha_{j-1} = 0 (parallel axes,
KR 1000 joint 3) dd_{j-1} cannot shift along y and dtheta_{j-1} does (a_{j-1} dtheta).
Joint 1 has no link before it: its motion is expressed in the frame that turns with
joint 1 (pivot at the base origin) and produced by link 1's deviations plus dd_2 and
dtheta_2. That frame turns with q1, which changes nothing: the set of clearance states
(a product of discs about the axis) and their distribution are invariant under rotations
about the axis. The map is linear and constant: deviations (M, n, 5) = states (M, 4n) @ D^T.

Prismatic joints (q adds to d, A_j = Rz(theta) Tz(d + q) ...): a slide j >= 2 is a rod
in two bushings of link j-1 (the seats are fixed on the link carrying the hole, as for a
revolute joint). The rod's axis is then the fixed line through the two seat offsets, and
the rod travels along it: link j-1's end frame, then the axis motion, then Tz(d + q). The
motion sits before the slide's translation exactly where it sits before a revolute
joint's rotation, and the by-products along / about z (dd_j, dtheta_j) commute with
Tz(q) as they do with Rz(q): the map above holds unchanged, constant in q. A prismatic
joint 1 (a linear track) has no link before it, and a motion fixed in the base frame
pushed through Tz(d + q) would change with q (the tilt times the travel): we model it as
a carriage whose bearing seats ride on the rail, so the motion is fixed in the frame
after Rz(theta) Tz(d + q) (pivot at the carriage) and produced, as for a revolute joint 1,
by link 1's deviations plus dd_2 and dtheta_2. tests/test_uncertainty_prismatic.py checks
both against the exact rigid motions inserted into the FK chain (second-order agreement).

`box` is the exact per-component bound of the deviations over all clearance states (max
of a linear function over a product of discs), plus the optional manufacturing
tolerance box, as an `Interval` (n, 5).

Default bearing lengths (`defaults`): the shaft diameters, see KR1000_BEARING_LENGTH_MM. Units: mm for
lengths, rad for angles; deviations are [dtheta rad, dd mm, da mm, dalpha rad, dbeta rad].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from torchcal.kinematics import mdh as K
from torchcal.kinematics.chain import Chain
from torchcal.errors import InputError
from torchcal.reliability.interval import Interval

# -- docs/paper.md Table 2 (KR 1000 Titan), per radius variable DV1..DV12 -------------------
KR1000_SEAT_NAMES = (
    "base shaft", "turntable hole", "turntable hole", "upper-arm shaft (front)",
    "upper-arm shaft (end)", "forearm link hole", "forearm link shaft", "forearm hole (front)",
    "forearm hole (end)", "wrist shaft", "wrist hole", "end-effector shaft",
)
KR1000_SEAT_JOINT = (1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6)  # 1-based joint of each DV
KR1000_RADII_MM = (100.0, 100.0, 68.5, 68.5, 49.5, 49.5, 37.8, 37.8, 30.0, 30.0, 25.0, 25.0)
KR1000_TOLERANCE_MM = (0.015, 0.022, 0.019, 0.013, 0.011, 0.016, 0.011, 0.016, 0.013, 0.009, 0.013, 0.009)
KR1000_LIMITS_MM = (
    (99.985, 100.0), (100.0, 100.022), (68.5, 68.519), (68.487, 68.5), (49.489, 49.5), (49.5, 49.516),
    (37.789, 37.8), (37.8, 37.816), (30.0, 30.013), (29.991, 30.0), (25.0, 25.013), (24.991, 25.0),
)
KR1000_CLEARANCE_MM = (0.027, 0.037, 0.022, 0.032, 0.027, 0.027, 0.027, 0.027, 0.022, 0.022, 0.000, 0.022)
KR1000_MIN_CLEARANCE_MM = (0.0,) * 12

# -- our simulated KR 1000 Titan (not in the paper) -----------------------------------
# Bearing length L_j (mm): axial distance between the two seats of joint j, taken equal to
# the shaft diameter (2 x the Table 2 radius of the joint: length / diameter = 1, a common
# journal-bearing proportion). The tilt (c_1 + c_2) / L_j is then 3.2e-4, 3.9e-4, 5.5e-4,
# 7.1e-4, 7.3e-4, 4.4e-4 rad for joints 1..6, and the sweep reproduces the paper's spread
# of reliability (Table 3: R_set 0.685 .. 1 at an allowed distance error of 2.5 mm):
# 100 points x 300 clearance states give R_set from 0.72 (seed 0; 0.75, 0.80, 0.77 for
# seeds 1-3) to 1, about half the points at 1, distance bounds 1.6 .. 3.5 mm. With
# seats 1.5 x as far apart every point has R_set = 1 (bounds 1.2 .. 2.3 mm); 0.85 x as
# far apart gives R_set 0.61 .. 1 with only 13 % of the points at 1. No manufacturing
# tolerance box is needed (``tolerance=None``).
KR1000_BEARING_LENGTH_MM = (200.0, 137.0, 99.0, 75.6, 60.0, 50.0)

MODES = ("contact", "disc")
#: the largest axis tilt (c_1 + c_2) / L of a joint a clearance model takes, rad: the
#: first-order map onto MD-H deviations assumes small motions (the KR 1000's are 3e-4 ..
#: 7e-4 rad); 30 "mm" of clearance (micrometres) or a bearing length of 0.15 "mm" (metres)
#: give 0.3 .. 0.5 rad and distance errors of hundreds of mm.
MAX_TILT_RAD = 0.01


@dataclass(frozen=True)
class ClearanceModel:
    """Shaft-in-hole clearance of every joint (two seats per joint).

    Attributes:
        radii_mm: (2n,) nominal seat radii, seat 2j-1 and 2j belong to joint j (1-based).
            Informative (the kinematic effect depends only on clearance and length).
        clearance_mm: (2n,) maximum radial clearance of each seat, >= 0.
        bearing_length_mm: (n,) axial distance between the two seats of each joint, > 0.
        mode: "contact" (shaft against the wall, |u| = c) or "disc" (|u| <= c, uniform).
        tolerance: optional (n, 5) half-widths of a manufacturing tolerance box of static
            MD-H deviations [dtheta rad, dd mm, da mm, dalpha rad, dbeta rad], sampled
            uniformly and added to the clearance deviations; None: no such box.
    """

    radii_mm: tuple
    clearance_mm: tuple
    bearing_length_mm: tuple
    mode: str = "contact"
    tolerance: tuple | None = None

    def __post_init__(self):
        for name in ("radii_mm", "clearance_mm", "bearing_length_mm"):
            v = getattr(self, name)
            try:
                v = tuple(float(x) for x in v)
            except (TypeError, ValueError):
                raise InputError(f"ClearanceModel.{name}: expected a sequence of numbers, got {v!r}") from None
            if not all(math.isfinite(x) for x in v):
                raise InputError(f"ClearanceModel.{name}: values must be finite, got {v}")
            object.__setattr__(self, name, v)
        n = len(self.bearing_length_mm)
        if n < 2:
            raise InputError(f"ClearanceModel.bearing_length_mm: need one length per joint (n >= 2), got {n}")
        if len(self.radii_mm) != 2 * n or len(self.clearance_mm) != 2 * n:
            raise InputError(f"ClearanceModel: expected 2n = {2 * n} seat radii and clearances for {n} joints, "
                             f"got {len(self.radii_mm)} radii and {len(self.clearance_mm)} clearances")
        if min(self.clearance_mm) < 0:
            raise InputError(f"ClearanceModel.clearance_mm: must be >= 0, got {min(self.clearance_mm)}")
        if min(self.bearing_length_mm) <= 0:
            raise InputError(f"ClearanceModel.bearing_length_mm: must be > 0, got {min(self.bearing_length_mm)}")
        if self.mode not in MODES:
            raise InputError(f"ClearanceModel.mode: expected one of {', '.join(MODES)}, got {self.mode!r}")
        if max(self.clearance_mm) == 0 and self.tolerance is None:
            raise InputError("ClearanceModel.clearance_mm: every seat's clearance is 0 (and no tolerance box): "
                             "no state differs from the nominal robot, so R_set would be 1 everywhere")
        tilt = [(self.clearance_mm[2 * j] + self.clearance_mm[2 * j + 1]) / self.bearing_length_mm[j] for j in range(n)]
        j = max(range(n), key=tilt.__getitem__)
        if tilt[j] > MAX_TILT_RAD:
            raise InputError(f"ClearanceModel: joint {j + 1}: clearances {self.clearance_mm[2 * j]:g} + "
                             f"{self.clearance_mm[2 * j + 1]:g} mm over a bearing length of "
                             f"{self.bearing_length_mm[j]:g} mm tilt its axis by up to {tilt[j]:.3g} rad, beyond "
                             f"the small motions a clearance model describes (at most {MAX_TILT_RAD:g} rad): "
                             "clearances in micrometres or bearing lengths in metres? both take mm")
        if self.tolerance is not None:
            tol = tuple(tuple(float(x) for x in row) for row in self.tolerance)
            if len(tol) != n or any(len(row) != 5 for row in tol) or min(min(r) for r in tol) < 0:
                raise InputError(f"ClearanceModel.tolerance: expected ({n}, 5) half-widths >= 0")
            object.__setattr__(self, "tolerance", tol)

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.bearing_length_mm)

    @classmethod
    def defaults(cls, robot) -> "ClearanceModel":
        """The robot's clearance model: its robot file's "clearance" section (`Robot.clearance`)
        if it has one, else Table 2 and KR1000_BEARING_LENGTH_MM for the kr1000titan preset;
        any other robot: InputError naming the two ways to give one."""
        if robot.clearance is not None:
            return clearance_from_dict(robot.clearance, f"robot {robot.name!r}: clearance", robot.n)
        if robot.name != "kr1000titan" or robot.n != 6 or bool(robot.prismatic.any()):
            raise InputError(f"no default clearance model for robot {robot.name!r} (only the kr1000titan preset has one): "
                             f"add a \"clearance\" section to its robot file or give a clearance model "
                             f"(keys radii_mm, clearance_mm, bearing_length_mm; docs/robots.md)",
                             fix=("clearance", "FILE.json"))
        return cls(KR1000_RADII_MM, KR1000_CLEARANCE_MM, KR1000_BEARING_LENGTH_MM)

    def to_dict(self) -> dict:
        """The "clearance" section / clearance file of this model (mm; no tolerance box)."""
        return {"radii_mm": list(self.radii_mm), "clearance_mm": list(self.clearance_mm),
                "bearing_length_mm": list(self.bearing_length_mm), "mode": self.mode}

    def max_shift_mm(self) -> torch.Tensor:
        """(n,) largest radial shift of each joint axis, (c_1 + c_2) / 2."""
        c = torch.tensor(self.clearance_mm, dtype=torch.float64).reshape(self.n, 2)
        return c.sum(-1) / 2

    def max_tilt_rad(self) -> torch.Tensor:
        """(n,) largest tilt of each joint axis, (c_1 + c_2) / L."""
        c = torch.tensor(self.clearance_mm, dtype=torch.float64).reshape(self.n, 2)
        return c.sum(-1) / torch.tensor(self.bearing_length_mm, dtype=torch.float64)

    # -- delegates -----------------------------------------------------------------------
    def sample_states(self, m: int, seed: torch.Generator | int | None = None, **kw) -> torch.Tensor:
        return sample_states(self, m, seed, **kw)

    def deviations(self, robot, states: torch.Tensor) -> torch.Tensor:
        return states_to_deviations(robot, self, states)

    def sample(self, robot, m: int, seed: torch.Generator | int | None = None, **kw) -> torch.Tensor:
        return sample_deviations(robot, self, m, seed, **kw)

    def box(self, robot) -> Interval:
        return box(robot, self)


CLEARANCE_KEYS = ("radii_mm", "clearance_mm", "bearing_length_mm", "mode")


def clearance_from_dict(obj, where: str, n: int | None = None) -> ClearanceModel:
    """The `ClearanceModel` of a robot file's "clearance" section or a clearance file.

    obj: {"radii_mm": [2n], "clearance_mm": [2n], "bearing_length_mm": [n], "mode":
    "contact" | "disc" (optional)}, mm; seats 2j-1 and 2j (1-based) belong to joint j.
    radii_mm is informative (the kinematics depend on clearance and length only) and may
    be left out (then 0). n: the robot's joint count, checked when given. One InputError
    line naming `where` and the key on any mistake.
    """
    if not isinstance(obj, dict):
        raise InputError(f"{where}: expected an object with keys radii_mm, clearance_mm, bearing_length_mm[, mode]")
    unknown = sorted(set(obj) - set(CLEARANCE_KEYS))
    if unknown:
        raise InputError(f"{where}: unknown key(s) {', '.join(unknown)}; expected {', '.join(CLEARANCE_KEYS)}")
    for key in ("clearance_mm", "bearing_length_mm"):
        if key not in obj:
            raise InputError(f"{where}: missing key {key!r}")
    for key in ("radii_mm", "clearance_mm", "bearing_length_mm"):
        v = obj.get(key, [])
        if not isinstance(v, list) or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
            raise InputError(f"{where}: {key}: expected a list of numbers (mm)")
    m = len(obj["bearing_length_mm"])
    if n is not None and m != n:
        raise InputError(f"{where}: bearing_length_mm: expected one length per joint ({n}), got {m}")
    radii = obj.get("radii_mm", [0.0] * (2 * m))
    try:
        return ClearanceModel(radii, obj["clearance_mm"], obj["bearing_length_mm"], obj.get("mode", "contact"))
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def _check_robot(robot, model: ClearanceModel):
    if robot.n != model.n:
        raise InputError(f"clearance model has {model.n} joints but robot {robot.name!r} has {robot.n}")


def _link_twist_columns(row: torch.Tensor) -> torch.Tensor:
    """G (6, 5) of docs/paper.md eq. 14: body twist [dx, dy, dz, deltax, deltay, deltaz] in the
    link's end frame per unit deviation [dtheta, dd, da, dalpha, dbeta].

    row (5,) nominal [theta_offset, d, a, alpha, beta]; G does not depend on theta or d.
    """
    a, alpha, beta = row[2], row[3], row[4]
    ca, sa, cb, sb = torch.cos(alpha), torch.sin(alpha), torch.cos(beta), torch.sin(beta)
    z = torch.zeros((), dtype=row.dtype)
    one = torch.ones((), dtype=row.dtype)
    return torch.stack([
        torch.stack([a * sa * sb, -ca * sb, cb, z, z]),
        torch.stack([a * ca, sa, z, z, z]),
        torch.stack([-a * sa * cb, ca * cb, sb, z, z]),
        torch.stack([-ca * sb, z, z, cb, z]),
        torch.stack([sa, z, z, z, one]),
        torch.stack([ca * cb, z, z, sb, z]),
    ])


def _solve_twist(G: torch.Tensor, xi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Host-link deviations p (5,) and next-link [dtheta, dd] (2,) whose twist equals xi.

    Solves G p + dtheta_next e_wz + dd_next e_vz = xi (in the host's end frame), with
    dtheta_host = 0 where that is solvable, else with dd_host = 0 (parallel axes).
    G (6, 5), xi (6, k) -> p (5, k), nxt (2, k).
    """
    ez = torch.zeros(6, 2, dtype=G.dtype)
    ez[5, 0] = 1.0  # dtheta_next: rotation about z
    ez[2, 1] = 1.0  # dd_next: translation along z
    for host_cols in ((1, 2, 3, 4), (0, 2, 3, 4)):
        A = torch.cat([G[:, host_cols], ez], dim=1)  # (6, 6)
        if torch.linalg.matrix_rank(A) == 6:
            sol = torch.linalg.solve(A, xi)
            p = torch.zeros(5, xi.shape[1], dtype=G.dtype)
            p[list(host_cols)] = sol[:4]
            return p, sol[4:]
    A = torch.cat([G, ez], dim=1)  # (6, 7), min-norm fallback
    sol = torch.linalg.lstsq(A, xi).solution
    return sol[:5], sol[5:]


def deviation_map(robot, model: ClearanceModel) -> torch.Tensor:
    """D (5n, 4n): flattened deviations (n, 5) = D @ flattened seat offsets (2n, 2) mm.

    Seat offsets: states[..., 2j, :] and states[..., 2j + 1, :] are the radial offsets
    (x, y in the frame of joint j's axis, mm) of joint j's first and second seat (0-based j).
    """
    _check_robot(robot, model)
    n = robot.n
    table = robot.table.to(torch.float64).cpu()
    L = torch.tensor(model.bearing_length_mm, dtype=torch.float64)
    D = torch.zeros(n, 5, 2 * n, 2, dtype=torch.float64)
    for j in range(n):
        # seat offsets (u1, u2) -> axis twist [tx, ty, tz, wx, wy, wz] at the pivot, (6, 2, 2)
        C = torch.zeros(6, 2, 2, dtype=torch.float64)
        C[0, :, 0] = 0.5  # shift = (u1 + u2) / 2
        C[1, :, 1] = 0.5
        # tilt: axis direction e_z + (u2 - u1) / L  ->  w x e_z = (u2 - u1) / L
        C[3, 0, 1], C[3, 1, 1] = 1.0 / L[j], -1.0 / L[j]  # wx = -(u2 - u1)_y / L
        C[4, 0, 0], C[4, 1, 0] = -1.0 / L[j], 1.0 / L[j]  # wy = (u2 - u1)_x / L
        xi = C.reshape(6, 4)
        if j == 0:
            host = 0
            # frame turning with joint 1 -> link 1's end frame: S = Tz(d) Tx(a) Rx(alpha) Ry(beta);
            # a prismatic joint 1 (carriage): frame after Rz(theta) Tz(d + q) -> S = Tx(a) Rx(alpha) Ry(beta)
            row = table[:1].clone()
            if bool(robot.prismatic[0]):
                row[0, 1] = 0.0
            S = K.link_transforms(-row[:, 0], Chain.revolute(row))[0]
            R, pos = S[:3, :3], S[:3, 3]
            v, w = xi[:3], xi[3:]
            xi = torch.cat([R.T @ (v + torch.linalg.cross(w.T, pos.expand(4, 3)).T), R.T @ w])
        else:
            host = j - 1
        G = _link_twist_columns(table[host])
        p, nxt = _solve_twist(G, xi)  # (5, 4), (2, 4)
        ez = torch.zeros(6, 2, dtype=torch.float64)
        ez[5, 0], ez[2, 1] = 1.0, 1.0
        if (G @ p + ez @ nxt - xi).abs().max() > 1e-9 * xi.abs().max():
            raise InputError(f"robot {robot.name!r}: the clearance motion of joint {j + 1}'s axis has no MD-H "
                             f"deviation of link {host + 1} (axes {host + 1} and {host + 2} coincide: parallel "
                             f"with a = 0); move one axis or drop that joint's clearance")
        D[host, :, 2 * j:2 * j + 2, :] += p.reshape(5, 2, 2)
        # the next link's dtheta / dd act about / along z of the host's end frame and
        # supply the z parts of xi that the host's deviations leave over (or cancel theirs)
        D[host + 1, 0, 2 * j:2 * j + 2, :] += nxt[0].reshape(2, 2)
        D[host + 1, 1, 2 * j:2 * j + 2, :] += nxt[1].reshape(2, 2)
    return D.reshape(5 * n, 4 * n)


def sample_states(model: ClearanceModel, m: int, seed: torch.Generator | int | None = None,
                  dtype=torch.float64, device=None) -> torch.Tensor:
    """Random clearance states: seat offsets (m, 2n, 2) mm (see `ClearanceModel.mode`).
    seed: a torch.Generator, an int seed for a new one, or None (torch's default generator)."""
    if not isinstance(m, int) or m < 1:
        raise InputError(f"number of clearance states must be a positive integer, got {m!r}")
    generator = torch.Generator().manual_seed(seed) if isinstance(seed, int) else seed
    c = torch.tensor(model.clearance_mm, dtype=torch.float64)
    phi = 2 * math.pi * torch.rand(m, c.shape[0], generator=generator, dtype=torch.float64)
    rad = c.expand(m, -1)
    if model.mode == "disc":
        rad = rad * torch.rand(m, c.shape[0], generator=generator, dtype=torch.float64).sqrt()
    u = torch.stack([rad * torch.cos(phi), rad * torch.sin(phi)], dim=-1)
    return u.to(device=device, dtype=dtype)


def states_to_deviations(robot, model: ClearanceModel, states: torch.Tensor) -> torch.Tensor:
    """Seat offsets (..., 2n, 2) mm -> MD-H deviations (..., n, 5) (first order)."""
    n = model.n
    if states.shape[-2:] != (2 * n, 2):
        raise InputError(f"clearance states: expected shape (..., {2 * n}, 2), got {tuple(states.shape)}")
    D = deviation_map(robot, model).to(device=states.device, dtype=states.dtype)
    flat = states.reshape(*states.shape[:-2], 4 * n)
    return (flat @ D.T).reshape(*states.shape[:-2], n, 5)


def sample_deviations(robot, model: ClearanceModel, m: int, seed: torch.Generator | int | None = None,
                      dtype=torch.float64, device=None) -> torch.Tensor:
    """m random deviation sets (m, n, 5): clearance states (+ the tolerance box, uniform).
    seed as in `sample_states`."""
    generator = torch.Generator().manual_seed(seed) if isinstance(seed, int) else seed
    states = sample_states(model, m, generator)
    dev = states_to_deviations(robot, model, states)
    if model.tolerance is not None:
        tol = torch.tensor(model.tolerance, dtype=torch.float64)
        dev = dev + (2 * torch.rand(m, model.n, 5, generator=generator, dtype=torch.float64) - 1) * tol
    return dev.to(device=device, dtype=dtype)


def box(robot, model: ClearanceModel) -> Interval:
    """Interval (n, 5) of the deviations over every clearance state (and the tolerance box).

    Component k: +-(sum over seats s of c_s |D[k, s]|_2) (+ tolerance), the exact range of
    a linear function over a product of discs, attained by some clearance state.
    """
    n = model.n
    D = deviation_map(robot, model).reshape(5 * n, 2 * n, 2)
    c = torch.tensor(model.clearance_mm, dtype=torch.float64)
    r = (D.norm(dim=-1) * c).sum(-1).reshape(n, 5)
    if model.tolerance is not None:
        r = r + torch.tensor(model.tolerance, dtype=torch.float64)
    return Interval(-r, r)
