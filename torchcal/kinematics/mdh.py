"""Batched MD-H kinematics: pure tensor kernels.

MD-H link transform (docs/paper.md eqs. 5-7), per joint i::

    A_i = Rot(z, theta_i) Trans(z, d_i) Trans(x, a_i) Rot(x, alpha_i) Rot(y, beta_i)

Conventions (inside torchcal): millimetres and radians, float64 unless the caller
passes float32. Shapes, batch dims first:

- ``table (n, 5)``: nominal [theta_offset rad, d mm, a mm, alpha rad, beta rad];
- ``q (..., n)`` rad: joint angles; the actual joint rotation is q + theta_offset + dtheta;
  for a prismatic joint q is in mm and adds to d instead (theta = theta_offset + dtheta);
- ``prismatic (n,) bool`` or None (all revolute): every kernel takes it as a keyword;
- ``params (..., n, 5)``: deviations [dtheta rad, dd mm, da mm, dalpha rad, dbeta rad]
  that broadcast against the batch dims of ``q``;
- ``base (4, 4)`` and ``tool (4, 4)`` homogeneous transforms (mm), world <- joint-1
  frame and flange <- TCP.

The kernels check nothing: `torchcal.robots.robot.Robot` validates user input once and calls
them. `fk_positions` chunks its work along the largest broadcast batch dim so that the
temporaries stay bounded (and cache-sized) whatever the batch.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import torch

PARAM_NAMES = ("dtheta", "dd", "da", "dalpha", "dbeta")
PARAM_UNITS = ("rad", "mm", "mm", "rad", "rad")

# elements per chunk of the position kernel: small enough for the temporaries to stay
# in the CPU caches, large enough to amortise the per-op overhead of torch.
DEFAULT_CHUNK = 1 << 16


def _effective(table: torch.Tensor, params: torch.Tensor | None):
    """Actual [theta_offset, d, a, alpha, beta] per joint: nominal + deviation.

    table (n, 5), params (..., n, 5) or None -> tuple of 5 tensors (..., n)
    """
    eff = table if params is None else table + params
    return eff.unbind(-1)


def _split(q, prismatic):
    """(rotation q, translation q or None): q (..., n) with prismatic (n,) bool or None."""
    if prismatic is None:
        return q, None
    return q.masked_fill(prismatic, 0.0), q.masked_fill(~prismatic, 0.0)


def link_transforms(q: torch.Tensor, table: torch.Tensor, params: torch.Tensor | None = None,
                    prismatic=None) -> torch.Tensor:
    """The MD-H link transforms A_i.

    q (..., n) rad / mm, table (n, 5), params (..., n, 5) or None -> (..., n, 4, 4) mm
    """
    off, d, a, alpha, beta = _effective(table, params)
    qr, qt = _split(q, prismatic)
    theta = qr + off
    if qt is not None:
        d = d + qt
    ct, st = torch.cos(theta), torch.sin(theta)
    ca, sa = torch.cos(alpha), torch.sin(alpha)
    cb, sb = torch.cos(beta), torch.sin(beta)
    ct, st, ca, sa, cb, sb, d, a = torch.broadcast_tensors(ct, st, ca, sa, cb, sb, d, a)
    zero, one = torch.zeros_like(ct), torch.ones_like(ct)
    # Rz(theta) Rx(alpha) columns, then Ry(beta) mixes columns 0 and 2
    c0 = (ct, st, zero)
    c1 = (-st * ca, ct * ca, sa)
    c2 = (st * sa, -ct * sa, ca)
    r0 = [cb * x - sb * z for x, z in zip(c0, c2)]
    r2 = [sb * x + cb * z for x, z in zip(c0, c2)]
    rows = [
        torch.stack([r0[k], c1[k], r2[k], t], dim=-1)
        for k, t in enumerate((a * ct, a * st, d))
    ]
    rows.append(torch.stack([zero, zero, zero, one], dim=-1))
    return torch.stack(rows, dim=-2)


def fk_frames(q, table, params=None, base=None, tool=None, prismatic=None) -> torch.Tensor:
    """World poses of every joint frame and of the TCP.

    q (..., n) rad, params (..., n, 5) or None, base/tool (4, 4) or None
    -> (..., n + 2, 4, 4): index 0 is the base (frame of joint 1's axis), index i the
    frame after link i, index n + 1 the TCP (last frame times tool).
    """
    A = link_transforms(q, table, params, prismatic)  # (..., n, 4, 4)
    batch = A.shape[:-3]
    eye = torch.eye(4, dtype=A.dtype, device=A.device)
    T = (eye if base is None else base.to(A)).expand(*batch, 4, 4)
    frames = [T]
    for i in range(A.shape[-3]):
        T = T @ A[..., i, :, :]
        frames.append(T)
    frames.append(T if tool is None else T @ tool.to(A))
    return torch.stack(frames, dim=-3)


def fk_pose(q, table, params=None, base=None, tool=None, prismatic=None) -> torch.Tensor:
    """TCP pose. q (..., n) rad / mm, params (..., n, 5) -> (..., 4, 4) mm."""
    A = link_transforms(q, table, params, prismatic)
    T = A[..., 0, :, :]
    for i in range(1, A.shape[-3]):
        T = T @ A[..., i, :, :]
    if base is not None:
        T = base.to(T) @ T
    if tool is not None:
        T = T @ tool.to(T)
    return T


class _JointList(list):
    """Per-joint tensors indexed like a (..., n) tensor: ``x[..., i]``."""

    def __getitem__(self, key):
        if isinstance(key, tuple):
            key = key[-1]
        return list.__getitem__(self, key)


def _rotate(R, i, w, start=None):
    """u = R_i w (+ start): rows of R (3 x 3 tensors (..., n)) at joint i, w 3 tensors."""
    u = []
    for r in range(3):
        acc = R[r][0][..., i] * w[0] if start is None else torch.addcmul(start[r], R[r][0][..., i], w[0])
        acc = torch.addcmul(acc, R[r][1][..., i], w[1])
        u.append(torch.addcmul(acc, R[r][2][..., i], w[2]))
    return u


def _positions_kernel(q, table, params, base, tool_point, out=None, prismatic=None):
    """TCP positions by a backward recursion over the links, 3-vectors only.

    With the offsets and deviations folded into R_i = Rz(off_i) Rx(alpha_i) Ry(beta_i),
    t_i = Rz(off_i) [a_i, 0, d_i] and k_i = R_i^T t_i, link i maps a point v of its end
    frame to Rz(q_i) R_i (v + k_i). From w = tool point + k_n::

        u = R_i w;  w <- Rz(q_i) u + k_(i-1)   for i = n .. 2
        p = B (R_1 w + B^T b),  B = R_base Rz(q_1)

    Only Rz(q_i) (and B) carry the pose batch, only R_i, k_i the parameter batch, so the
    full broadcast batch sees 14 multiply-adds per joint, each a single fused torch op
    with at most one operand broadcast along the innermost dim (vectorised on CPU).

    q (..., n) rad, table (n, 5), params (..., n, 5) or None, base (4, 4) or None,
    tool_point (..., 3) mm -> (..., 3) mm. With `out` (a (..., 3) view of the broadcast
    shape) the result is written there instead of stacked (saves a copy; not for vmap).
    A prismatic joint i (``prismatic (n,) bool``) has Rz(q_i) = I and k_i + q_i R_i^T e_z.
    """
    n = table.shape[0]
    off, d, a, alpha, beta = _effective(table, params)  # each (..., n) or (n,)
    co, so = torch.cos(off), torch.sin(off)
    ca, sa = torch.cos(alpha), torch.sin(alpha)
    cb, sb = torch.cos(beta), torch.sin(beta)
    sasb, sacb = sa * sb, sa * cb
    # rows of Rz(off) Rx(alpha) Ry(beta); Rx Ry = [[cb, 0, sb], [sa sb, ca, -sa cb], [-ca sb, sa, ca cb]]
    R = ((co * cb - so * sasb, -so * ca, co * sb + so * sacb),
         (so * cb + co * sasb, co * ca, so * sb - co * sacb),
         (-ca * sb, sa, ca * cb))  # each (..., n)
    tx, ty = co * a, so * a  # t = Rz(off) [a, 0, d]
    k = [R[0][c] * tx + R[1][c] * ty + R[2][c] * d for c in range(3)]  # R^T t, each (..., n)
    qj = q.movedim(-1, 0)  # (n, ...): one contiguous block of angles per joint
    if prismatic is not None:
        lin = prismatic.nonzero().flatten().tolist()
        qt = qj[lin]  # (p, ...) mm
        qj = qj.masked_fill(prismatic.view(-1, *([1] * (qj.ndim - 1))), 0.0)
        # k_i + q_i R_i^T e_z: row 2 of R_i, now with the pose batch
        k = [list(kc.unbind(-1)) for kc in k]
        for m, i in enumerate(lin):
            for c in range(3):
                k[c][i] = k[c][i] + qt[m] * R[2][c][..., i]
        k = [_JointList(kc) for kc in k]
    cq, sq = torch.cos(qj).contiguous(), torch.sin(qj).contiguous()
    w = [p + kc[..., n - 1] for p, kc in zip(tool_point.unbind(-1), k)]
    for i in range(n - 1, 0, -1):
        u = _rotate(R, i, w)
        c, s = cq[i], sq[i]
        w = [torch.addcmul(torch.addcmul(k[0][..., i - 1], c, u[0]), s, u[1], value=-1.0),
             torch.addcmul(torch.addcmul(k[1][..., i - 1], s, u[0]), c, u[1]),
             u[2] + k[2][..., i - 1]]
    c, s = cq[0], sq[0]
    if base is None:
        u = _rotate(R, 0, w)
        v = [torch.addcmul(c * u[0], s, u[1], value=-1.0), torch.addcmul(s * u[0], c, u[1]), u[2]]
    else:
        Rb, b = base[:3, :3], base[:3, 3]
        B = [(Rb[r, 0] * c + Rb[r, 1] * s, Rb[r, 1] * c - Rb[r, 0] * s, Rb[r, 2]) for r in range(3)]
        h = [B[0][j] * b[0] + B[1][j] * b[1] + B[2][j] * b[2] for j in range(3)]  # B^T b, pose batch
        u = _rotate(R, 0, w, start=h)
        v = [torch.addcmul(torch.addcmul(Br[0] * u[0], Br[1], u[1]), Br[2], u[2]) for Br in B]
    if out is None:
        return torch.stack(torch.broadcast_tensors(*v), dim=-1)
    for j in range(3):
        out[..., j].copy_(v[j])
    return out


def fk_positions(q, table, params=None, base=None, tool=None, chunk: int = DEFAULT_CHUNK,
                 prismatic=None) -> torch.Tensor:
    """TCP positions for every (pose, parameter set) of the broadcast batch.

    q (..., n) rad, params (..., n, 5) or None -> (..., 3) mm.
    Work is cut along the largest broadcast batch dim into pieces of about `chunk`
    evaluations, so temporaries stay bounded; the output is the full (..., 3).
    """
    tool_point = (torch.zeros(3, dtype=table.dtype, device=table.device) if tool is None
                  else tool[:3, 3].to(table))
    base = None if base is None else base.to(table)
    if base is not None and torch.equal(base, torch.eye(4, dtype=base.dtype, device=base.device)):
        base = None  # the usual case: skip the base rotation on the full batch
    qb = q.shape[:-1]
    pb = () if params is None else params.shape[:-2]
    batch = torch.broadcast_shapes(qb, pb)
    total = math.prod(batch)
    if total <= chunk or len(batch) == 0:
        return _positions_kernel(q, table, params, base, tool_point, prismatic=prismatic)
    # align leading dims, pick the largest batch dim to cut along
    q = q.reshape((1,) * (len(batch) - len(qb)) + q.shape)
    if params is not None:
        params = params.reshape((1,) * (len(batch) - len(pb)) + params.shape)
    dim = max(range(len(batch)), key=lambda k: batch[k])
    step = max(1, chunk * batch[dim] // total)
    out = torch.empty(*batch, 3, dtype=table.dtype, device=table.device)

    def run(start):
        size = min(step, batch[dim] - start)
        qc = q.narrow(dim, start, size) if q.shape[dim] > 1 else q
        pc = params
        if params is not None and params.shape[dim] > 1:
            pc = params.narrow(dim, start, size)
        _positions_kernel(qc, table, pc, base, tool_point, out=out.narrow(dim, start, size), prismatic=prismatic)

    starts = range(0, batch[dim], step)
    workers = min(torch.get_num_threads(), len(starts)) if out.device.type == "cpu" else 1
    if workers <= 1:
        for start in starts:
            run(start)
        return out
    _map_single_threaded(run, starts, workers)
    return out


def _map_single_threaded(fn, items, workers: int) -> None:
    """fn(item) for every item, on `workers` Python threads that each run torch with one
    intra-op thread. The chunks are handed out one at a time, so a thread that the OS
    deschedules (a busy machine) delays only its current chunk; the threads meet once,
    at the end, instead of at a barrier in every torch op (docs/performance.md)."""
    before = torch.get_num_threads()

    def one(item):
        torch.set_num_threads(1)
        fn(item)

    try:
        with ThreadPoolExecutor(workers) as pool:
            for _ in pool.map(one, items):
                pass
    finally:
        torch.set_num_threads(before)


class ChainJacobians(NamedTuple):
    """Derivatives of the TCP of one MD-H chain (`chain_jacobians`), frame of `base`.

    position (..., 3) mm; rotation (..., 3, 3) (flange rotation, the tool point does not
    rotate it); dq (..., 3, n) d position / d q (mm/rad, mm/mm prismatic);
    dparams (..., 3, 5n) d position / d deviations (columns as ``params.reshape(..., 5n)``);
    wq (..., 3, n) and wparams (..., 3, 5n): the angular velocity of the TCP frame per unit
    of q and of the deviations (rad per unit), i.e. d rotation = [w]x rotation.
    """

    position: torch.Tensor
    rotation: torch.Tensor
    dq: torch.Tensor
    dparams: torch.Tensor
    wq: torch.Tensor
    wparams: torch.Tensor


def chain_jacobians(q, table, params=None, base=None, tool_point=None, prismatic=None) -> ChainJacobians:
    """Analytic TCP Jacobians w.r.t. q and the MD-H deviations (docs/paper.md eqs. 14-18).

    q (..., n) rad / mm, table (n, 5), params (..., n, 5) or None, base (4, 4) or None,
    tool_point (..., 3) mm in the flange frame or None -> `ChainJacobians`.
    The TCP's derivative w.r.t. the tool point is ``rotation`` (mm/mm).

    For link i with input frame F (world pose of joint i's axis) and TCP p:
    dtheta rotates about z_F through o_F, dd translates along z_F, da along the x axis
    after Rz(theta), dalpha rotates about that x axis and dbeta about the y axis after
    Rx(alpha), both through the link's end origin o_i. A revolute q_i acts as dtheta_i,
    a prismatic one as dd_i.
    """
    frames = fk_frames(q, table, params, base, None, prismatic)  # (..., n+2, 4, 4), last = flange
    n = table.shape[0]
    R = frames[..., -1, :3, :3]
    p = frames[..., -1, :3, 3]
    if tool_point is not None:
        p = p + (R @ tool_point.to(R).unsqueeze(-1)).squeeze(-1)
    F = frames[..., :n, :, :]  # input frame of each link (..., n, 4, 4)
    z, o = F[..., :3, 2], F[..., :3, 3]
    off, d, a, alpha, beta = _effective(table, params)
    theta = _split(q, prismatic)[0] + off
    ct, st = torch.cos(theta).unsqueeze(-1), torch.sin(theta).unsqueeze(-1)
    ca, sa = torch.cos(alpha).unsqueeze(-1), torch.sin(alpha).unsqueeze(-1)
    x_mid = F[..., :3, 0] * ct + F[..., :3, 1] * st  # R Rz(theta) e_x
    y_rz = -F[..., :3, 0] * st + F[..., :3, 1] * ct  # R Rz(theta) e_y
    y_mid = y_rz * ca + z * sa  # R Rz Rx(alpha) e_y
    o_end = frames[..., 1:n + 1, :3, 3]
    pp = p.unsqueeze(-2)
    x_mid, y_mid, z, o, o_end, pp = torch.broadcast_tensors(x_mid, y_mid, z, o, o_end, pp)
    zero = torch.zeros_like(z)
    rot_z = torch.linalg.cross(z, pp - o)
    cols = torch.stack([rot_z, z, x_mid,
                        torch.linalg.cross(x_mid, pp - o_end),
                        torch.linalg.cross(y_mid, pp - o_end)], dim=-1)  # (..., n, 3, 5)
    wcols = torch.stack([z, zero, zero, x_mid, y_mid], dim=-1)
    batch = cols.shape[:-3]
    dparams = cols.movedim(-3, -2).reshape(*batch, 3, 5 * n)
    wparams = wcols.movedim(-3, -2).reshape(*batch, 3, 5 * n)
    dq, wq = rot_z, z
    if prismatic is not None:
        lin = prismatic.unsqueeze(-1)
        dq, wq = torch.where(lin, z, rot_z), torch.where(lin, zero, z)
    return ChainJacobians(p, R, dq.transpose(-1, -2), dparams, wq.transpose(-1, -2), wparams)


def param_jacobian(q, table, params=None, base=None, tool=None, prismatic=None) -> torch.Tensor:
    """Analytic position Jacobian dP/d[params] (docs/paper.md eqs. 14-18).

    q (..., n) rad, params (..., n, 5) or None -> (..., 3, 5n), columns ordered as
    ``params.reshape(..., 5n)``: joint 1's [dtheta, dd, da, dalpha, dbeta], joint 2's...
    Units: mm/rad for angle columns, mm/mm for length columns (`chain_jacobians`).
    """
    tp = None if tool is None else tool[:3, 3]
    return chain_jacobians(q, table, params, base, tp, prismatic).dparams


def joint_jacobian(q, table, params=None, base=None, tool=None, prismatic=None) -> torch.Tensor:
    """Position Jacobian dP/dq. q (..., n) rad / mm -> (..., 3, n) mm/rad (revolute
    columns: z x (p - o)) or mm/mm (prismatic columns: z)."""
    tp = None if tool is None else tool[:3, 3]
    return chain_jacobians(q, table, params, base, tp, prismatic).dq


def outer_factors(table: torch.Tensor, dev: torch.Tensor) -> list[torch.Tensor]:
    """Per-set trig and lengths of the perturbed links: 8 tensors (n, M).

    table (n, 5), dev (M, n, 5) -> cos/sin of (theta_offset + dtheta), of alpha, of beta,
    then a and d, each transposed to (n, M) so that joint i's row is contiguous.
    """
    off, d, a, alpha, beta = (table + dev).unbind(-1)  # each (M, n)
    return [t.T.contiguous() for t in (torch.cos(off), torch.sin(off), torch.cos(alpha), torch.sin(alpha),
                                       torch.cos(beta), torch.sin(beta), a, d)]


def outer_positions(cq, sq, F, tool_point, bufs, tz=None):
    """TCP positions in the joint-1 frame for (Nc points) x (Mc sets), in place.

    The outer-product layout of the backward recursion of `_positions_kernel` (which
    serves any broadcast batch and autograd); this one serves the sweep's blocks,
    v <- Rz(q + off) (Rx(alpha) Ry(beta) v + [a, 0, d]), with every full-size temporary
    in one of the 7 preallocated buffers (Nc, Mc) and fused multiply-adds (addcmul):
    18 full-size operations per joint and no allocation, several times faster than the
    general kernel on a CPU. cq, sq (n, Nc) cos / sin of q; F: `outer_factors` sliced to
    the Mc sets; tool_point (3,). Returns three (Nc, Mc) views into `bufs`.
    Prismatic joints: tz, a list of n entries, None (revolute) or the joint's travel
    (Nc,) mm, which adds to d (pass cos / sin of 0 for that joint in cq, sq).
    """
    tz = [None] * cq.shape[0] if tz is None else tz
    co, so, ca, sa, cb, sb, a, d = F
    ct, st, b0, b1, b2, b3, b4 = bufs
    n = cq.shape[0]
    vx, vy, vz = tool_point[0], tool_point[1], tool_point[2]
    i = n - 1
    # last link: v is the tool point, its first half-step is per set only
    cqi, sqi = cq[i][:, None], sq[i][:, None]
    torch.mul(cqi, co[i], out=ct).addcmul_(sqi, so[i], value=-1)  # cos(q + off)
    torch.mul(sqi, co[i], out=st).addcmul_(cqi, so[i])  # sin(q + off)
    wx = cb[i] * vx + sb[i] * vz  # (Mc,)
    wz = cb[i] * vz - sb[i] * vx
    ux = wx + a[i]
    uy = ca[i] * vy - sa[i] * wz
    uz = sa[i] * vy + ca[i] * wz + d[i]
    vx = torch.mul(ct, ux, out=b0).addcmul_(st, uy, value=-1)
    vy = torch.mul(st, ux, out=b1).addcmul_(ct, uy)
    vz = b2.copy_(uz.expand_as(b2))
    if tz[i] is not None:
        vz.add_(tz[i][:, None])
    free = (b3, b4)
    for i in range(n - 2, -1, -1):
        cqi, sqi = cq[i][:, None], sq[i][:, None]
        torch.mul(cqi, co[i], out=ct).addcmul_(sqi, so[i], value=-1)
        torch.mul(sqi, co[i], out=st).addcmul_(cqi, so[i])
        wx, wz = free
        torch.mul(vx, cb[i], out=wx).addcmul_(vz, sb[i])  # Ry(beta) v
        torch.mul(vz, cb[i], out=wz).addcmul_(vx, sb[i], value=-1)
        ux = wx.add_(a[i])
        uy = torch.mul(vy, ca[i], out=vx).addcmul_(wz, sa[i], value=-1)  # Rx(alpha) ...
        uz = torch.mul(vy, sa[i], out=vz).addcmul_(wz, ca[i]).add_(d[i])
        if tz[i] is not None:
            uz.add_(tz[i][:, None])
        nvx = torch.mul(ct, ux, out=vy).addcmul_(st, uy, value=-1)  # Rz(theta) u
        nvy = torch.mul(st, ux, out=wz).addcmul_(ct, uy)
        vx, vy, vz = nvx, nvy, uz
        free = (ux, uy)
    return vx, vy, vz
