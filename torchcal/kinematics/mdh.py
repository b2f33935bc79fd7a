"""Batched MD-H kinematics: pure tensor kernels.

MD-H link transform (docs/paper.md eqs. 5-7), per joint i::

    A_i = Rot(z, theta_i) Trans(z, d_i) Trans(x, a_i) Rot(x, alpha_i) Rot(y, beta_i)

Conventions (inside torchcal): millimetres and radians, float64 unless the caller
passes float32. Shapes, batch dims first:

- ``chain``: a `torchcal.kinematics.chain.Chain`, the structure every kernel takes: the
  nominal table (n, 5) [theta_offset rad, d mm, a mm, alpha rad, beta rad], the joint
  types (prismatic (n,) bool), base (4, 4) world <- joint-1 frame and tool (4, 4)
  flange <- TCP (mm). The kernels use it in the dtype and device it has
  (``chain.to(q)`` casts it);
- ``q (..., n)`` rad: joint angles; the actual joint rotation is q + theta_offset + dtheta;
  for a prismatic joint q is in mm and adds to d instead (theta = theta_offset + dtheta);
- ``params (..., n, 5)``: deviations [dtheta rad, dd mm, da mm, dalpha rad, dbeta rad]
  that broadcast against the batch dims of ``q``.

The kernels check nothing: `torchcal.robots.robot.Robot` validates user input once and calls
them. `fk_positions` chunks its work along the largest broadcast batch dim so that the
temporaries stay bounded (and cache-sized) whatever the batch; without gradients on a CPU it
runs the compiled kernel of `torchcal.kinematics.fk_native` instead (fk_kernel.c, the
recursion of `positions_into` in registers; `pose_rows`, `link_rows` and `native_frames`
make its inputs), and `positions_into` stays the reference and the fallback.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np

import torch

from torchcal import threads
from torchcal.kinematics import fk_native
from torchcal.kinematics.chain import Chain

PARAM_NAMES = ("dtheta", "dd", "da", "dalpha", "dbeta")
PARAM_UNITS = ("rad", "mm", "mm", "rad", "rad")

# elements per chunk of the position kernel: small enough for the temporaries to stay
# in the CPU caches, large enough to amortise the per-op overhead of torch.
DEFAULT_CHUNK = 1 << 16
# on a GPU: large enough to fill the device and amortise each kernel launch (4M pairs hold
# about 1 GB of float64 temporaries)
DEFAULT_CHUNK_GPU = 1 << 22


# pairs per chunk of the in-place kernel `positions_into` on a CPU, by dtype, where it
# differs from DEFAULT_CHUNK. Its temporaries (u and nu, 3 rows each, and z, 2 rows) at
# 65536 float64 pairs take 4 MiB and spill a core's 2 MiB L2 on every op; at 16384 they take
# 1 MiB. Measured on the Xeon development machine (docs/performance.md): float64 FK per CPU
# second 1.3x faster at 16384 than at 65536 (32768 and 8192 between); float32 keeps 65536
# (2 MiB; 32768 ran at 0.87-1.07x of it, its ops cost half as much per pair, so the per-op
# overhead weighs more).
IN_PLACE_CHUNK = {torch.float64: 1 << 14}


def chunk_for(device, dtype=None) -> int:
    """Elements per chunk of the position kernel on `device` (a torch.device or str); with
    `dtype`, of the in-place kernel `positions_into` (on a CPU: `IN_PLACE_CHUNK`, else
    DEFAULT_CHUNK)."""
    if torch.device(device).type != "cpu":
        return DEFAULT_CHUNK_GPU
    return IN_PLACE_CHUNK.get(dtype, DEFAULT_CHUNK)


def _effective(table: torch.Tensor, params: torch.Tensor | None):
    """Actual [theta_offset, d, a, alpha, beta] per joint: nominal + deviation.

    table (n, 5), params (..., n, 5) or None -> tuple of 5 tensors (..., n)
    """
    eff = table if params is None else table + params
    return eff.unbind(-1)


def _split(q, chain: Chain):
    """(rotation q, translation q or None): q (..., n); None when no joint is prismatic."""
    if not chain.linear:
        return q, None
    return q.masked_fill(chain.prismatic, 0.0), q.masked_fill(~chain.prismatic, 0.0)


def link_transforms(q: torch.Tensor, chain: Chain, params: torch.Tensor | None = None) -> torch.Tensor:
    """The MD-H link transforms A_i (the table and joint types of `chain`).

    q (..., n) rad / mm, params (..., n, 5) or None -> (..., n, 4, 4) mm
    """
    off, d, a, alpha, beta = _effective(chain.table, params)
    qr, qt = _split(q, chain)
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


def fk_frames(q, chain: Chain, params=None) -> torch.Tensor:
    """World poses of every joint frame and of the TCP.

    q (..., n) rad / mm, params (..., n, 5) or None
    -> (..., n + 2, 4, 4) mm: index 0 is the base (frame of joint 1's axis), index i the
    frame after link i, index n + 1 the TCP (last frame times tool).
    """
    A = link_transforms(q, chain, params)  # (..., n, 4, 4)
    batch = A.shape[:-3]
    T = chain.base.to(A).expand(*batch, 4, 4)
    frames = [T]
    for i in range(A.shape[-3]):
        T = T @ A[..., i, :, :]
        frames.append(T)
    frames.append(T if chain.plain_tool else T @ chain.tool.to(A))
    return torch.stack(frames, dim=-3)


def fk_rotation(q, chain: Chain, params=None) -> torch.Tensor:
    """TCP rotation, world <- TCP: q (..., n) rad / mm, params (..., n, 5) or None ->
    (..., 3, 3), the rotation block of `fk_pose` (the same numbers), from a walk of the
    link axes without their origins."""
    if not chain.plain_tool:
        return fk_pose(q, chain, params)[..., :3, :3]
    *_, (X, Y, Z, _) = _walk(q, chain, params, with_origins=False)
    return torch.stack(torch.broadcast_tensors(X, Y, Z), dim=-1)


def tcp_frame(q, chain: Chain, params=None, *, tool_point=None) -> tuple[torch.Tensor, torch.Tensor]:
    """(TCP position (..., 3) mm, flange rotation (..., 3, 3)), world <- flange, from one
    walk of the link frames (`_walk`): the position of `positions` and the rotation of
    `fk_rotation` (a chain with a plain tool) to rounding, where those two are two walks.
    q (..., n) rad / mm, params (..., n, 5) or None, tool_point (..., 3) mm in the flange
    frame (None: ``chain.tool[:3, 3]``); the chain's tool rotation is not applied."""
    if tool_point is None:
        tool_point = chain.tool[:3, 3].to(chain.table)
    *_, (X, Y, Z, o) = _walk(q, chain, params)
    t = tool_point.unsqueeze(-1)  # (..., 3, 1): the flange-frame coordinates, one per axis
    p = torch.addcmul(torch.addcmul(torch.addcmul(o, X, t[..., 0, :]), Y, t[..., 1, :]), Z, t[..., 2, :])
    return p, torch.stack(torch.broadcast_tensors(X, Y, Z), dim=-1)


def fk_pose(q, chain: Chain, params=None) -> torch.Tensor:
    """TCP pose, world <- TCP. q (..., n) rad / mm, params (..., n, 5) or None -> (..., 4, 4) mm."""
    *_, (X, Y, Z, o) = _walk(q, chain, params)  # the flange, from the base
    top = torch.stack(torch.broadcast_tensors(X, Y, Z, o), dim=-1)  # (..., 3, 4)
    last = torch.zeros(4, dtype=top.dtype, device=top.device)
    last[3] = 1.0
    T = torch.cat([top, last.expand(*top.shape[:-2], 1, 4)], dim=-2)
    if not chain.plain_tool:
        T = T @ chain.tool.to(T)
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


def _link_rotations(table, params):
    """R_i = Rz(off_i) Rx(alpha_i) Ry(beta_i) and t_i = Rz(off_i) [a_i, 0, d_i] of every link.

    table (n, 5), params (..., n, 5) or None -> (R, t): R rows, a 3 x 3 nest of tensors
    (..., n); t, 3 tensors (..., n) mm (the deviations' batch, or (n,) without them).
    """
    off, d, a, alpha, beta = _effective(table, params)  # each (..., n) or (n,)
    co, so = torch.cos(off), torch.sin(off)
    ca, sa = torch.cos(alpha), torch.sin(alpha)
    cb, sb = torch.cos(beta), torch.sin(beta)
    sasb, sacb = sa * sb, sa * cb
    # rows of Rz(off) Rx(alpha) Ry(beta); Rx Ry = [[cb, 0, sb], [sa sb, ca, -sa cb], [-ca sb, sa, ca cb]]
    R = ((co * cb - so * sasb, -so * ca, co * sb + so * sacb),
         (so * cb + co * sasb, co * ca, so * sb - co * sacb),
         (-ca * sb, sa, ca * cb))
    return R, (co * a, so * a, d)


def positions(q, chain: Chain, params=None, *, tool_point=None, out=None) -> torch.Tensor:
    """TCP positions (world frame) by a backward recursion over the links, 3-vectors only.

    q (..., n) rad (revolute) / mm (prismatic), params (..., n, 5) MD-H deviations
    [dtheta rad, dd mm, da mm, dalpha rad, dbeta rad] or None, tool_point (..., 3) mm in
    the flange frame (None: the chain's tool point ``chain.tool[:3, 3]``) -> (..., 3) mm,
    the broadcast batch of q, params and tool_point. Differentiable (autograd, vmap).
    With `out` (a (..., 3) view of the broadcast shape) the result is written there
    instead of stacked (saves a copy; not for vmap). `fk_positions` runs this kernel in
    chunks for large batches; ``chain.local`` gives positions in the joint-1 frame.

    With the offsets and deviations folded into R_i = Rz(off_i) Rx(alpha_i) Ry(beta_i),
    t_i = Rz(off_i) [a_i, 0, d_i] and k_i = R_i^T t_i, link i maps a point v of its end
    frame to Rz(q_i) R_i (v + k_i). From w = tool point + k_n::

        u = R_i w;  w <- Rz(q_i) u + k_(i-1)   for i = n .. 2
        p = B (R_1 w + B^T b),  B = R_base Rz(q_1)

    Only Rz(q_i) (and B) carry the pose batch, only R_i, k_i the parameter batch, so the
    full broadcast batch sees 14 multiply-adds per joint, each a single fused torch op
    with at most one operand broadcast along the innermost dim (vectorised on CPU).

    A prismatic joint i has Rz(q_i) = I and k_i + q_i R_i^T e_z.
    """
    table = chain.table
    n = table.shape[0]
    if tool_point is None:
        tool_point = chain.tool[:3, 3].to(table)
    R, (tx, ty, d) = _link_rotations(table, params)  # each (..., n) or (n,)
    k = [R[0][c] * tx + R[1][c] * ty + R[2][c] * d for c in range(3)]  # R^T t, each (..., n)
    qj = q.movedim(-1, 0)  # (n, ...): one contiguous block of angles per joint
    if chain.linear:
        lin = list(chain.linear)
        qt = qj[lin]  # (p, ...) mm
        qj = qj.masked_fill(chain.prismatic.view(-1, *([1] * (qj.ndim - 1))), 0.0)
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
    if chain.plain_base:
        u = _rotate(R, 0, w)
        v = [torch.addcmul(c * u[0], s, u[1], value=-1.0), torch.addcmul(s * u[0], c, u[1]), u[2]]
    else:
        base = chain.base
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


def positions_into(q, chain: Chain, params, out: torch.Tensor) -> torch.Tensor:
    """TCP positions written into `out`, every full-size temporary in 3 reused buffers.

    q (..., n) rad / mm, params (..., n, 5) or None, out (..., 3) mm: a tensor (or a view)
    of the broadcast batch; the tool point is the chain's. Not differentiable (in-place
    ops): `fk_positions` calls it when no input needs a gradient, `positions` otherwise.

    The recursion of `positions` with t_i = R_i k_i = Rz(off_i) [a_i, 0, d_i] folded in::

        u_(n-1) = R_(n-1) tool + t_(n-1)                 (deviation batch only)
        u_i = R_i Rz(q_(i+1)) u_(i+1) + t_i              for i = n-2 .. 0
        p = R_base Rz(q_1) u_0 + b

    The three rows of u are one (3, ...) tensor, so a joint costs 6 fused torch ops
    (2 for Rz(q), 4 for R_i z + t_i) over 13 multiply-adds per pair; a prismatic joint's
    travel adds to the z of t_i.
    """
    batch = out.shape[:-1]
    q = q.reshape((1,) * (len(batch) + 1 - q.ndim) + q.shape)
    if params is not None:
        params = params.reshape((1,) * (len(batch) + 2 - params.ndim) + params.shape)
    return _positions_into(_PoseFactors.of(q, chain), _LinkFactors.of(chain.table, params, len(batch)),
                           chain, out)


class _PoseFactors(NamedTuple):
    """The pose batch of `positions_into`, joint first: cs (n, 2, ...) [cos, sin] and
    sc (n, 2, ...) [-sin, cos] of the joint rotations (0 at a prismatic joint), q (n, ...)
    rad / mm."""

    cs: torch.Tensor
    sc: torch.Tensor
    q: torch.Tensor

    @classmethod
    def of(cls, q, chain: Chain) -> "_PoseFactors":
        """q (..., n) -> factors with the batch dims of q."""
        qj = q.movedim(-1, 0)
        qr = qj
        if chain.linear:
            qr = qj.masked_fill(chain.prismatic.view(-1, *([1] * (qj.ndim - 1))), 0.0)
        c, s = torch.cos(qr), torch.sin(qr)
        return cls(torch.stack([c, s], 1), torch.stack([-s, c], 1), qj)

    def narrow(self, dim, start, size) -> "_PoseFactors":
        """The slice start:start+size of batch dim `dim` (a size-1 dim is kept, it broadcasts)."""
        return _PoseFactors(_narrow(self.cs, dim + 2, start, size), _narrow(self.sc, dim + 2, start, size),
                            _narrow(self.q, dim + 1, start, size))


class _LinkFactors(NamedTuple):
    """The deviation batch of `positions_into`: R (3, 3, n, ...) rows of
    R_i = Rz(off_i) Rx(alpha_i) Ry(beta_i); t (3, n, ...) mm, t_i = Rz(off_i) [a_i, 0, d_i]."""

    R: torch.Tensor
    t: torch.Tensor

    @classmethod
    def of(cls, table, params, ndim: int) -> "_LinkFactors":
        """table (n, 5), params (..., n, 5) or None -> factors with `ndim` batch dims."""
        R, t = _link_rotations(table, params)
        R = torch.stack([torch.stack(row) for row in R]).movedim(-1, 2)  # (3, 3, n, ...)
        t = torch.stack(t).movedim(-1, 1)  # (3, n, ...)
        R = R.reshape(R.shape[:3] + (1,) * (ndim + 3 - R.ndim) + R.shape[3:]).contiguous()
        return cls(R, t.reshape(t.shape[:2] + (1,) * (ndim + 2 - t.ndim) + t.shape[2:]).contiguous())

    def narrow(self, dim, start, size) -> "_LinkFactors":
        """The slice start:start+size of batch dim `dim` (a size-1 dim is kept, it broadcasts)."""
        return _LinkFactors(_narrow(self.R, dim + 3, start, size), _narrow(self.t, dim + 2, start, size))


def _narrow(x, dim, start, size):
    return x.narrow(dim, start, size) if x.shape[dim] > 1 else x


def _positions_into(pose: _PoseFactors, link: _LinkFactors, chain: Chain, out):
    """`positions_into` on precomputed factors whose batch dims align with `out`'s.

    The per-joint operands are views made by a few `unbind` calls per chunk, not one
    indexing call each (an index like ``R[:, 2, i]`` costs a few microseconds of Python,
    about a third of a 16384-pair chunk's time when every operand was indexed)."""
    n = chain.n
    shape = out.shape[:-1]
    R = [Ri.unbind(1) for Ri in link.R.unbind(2)]  # R[i][k]: column k of R_i, (3, ...)
    t = link.t.unbind(1)  # t[i]: (3, ...) mm
    cs, sc = pose.cs.unbind(0), pose.sc.unbind(0)  # per joint (2, ...)
    tp = chain.tool[:3, 3]
    i = n - 1
    u = R[i][0] * tp[0] + R[i][1] * tp[1] + R[i][2] * tp[2] + t[i]  # (3, ...) mm
    z = torch.empty((2,) + shape, dtype=out.dtype, device=out.device)
    z0, z1 = z.unbind(0)
    u, nu = (torch.empty((3,) + shape, dtype=out.dtype, device=out.device).copy_(u.expand((3,) + shape)),
             torch.empty((3,) + shape, dtype=out.dtype, device=out.device))
    ur, nur = u.unbind(0), nu.unbind(0)  # their rows
    if i in chain.linear:
        ur[2].add_(pose.q[i])
    for i in range(n - 2, -1, -1):
        torch.mul(cs[i + 1], ur[0], out=z).addcmul_(sc[i + 1], ur[1])  # Rz(q_(i+1)) u, rows 0, 1
        Ri = R[i]
        torch.mul(Ri[2], ur[2], out=nu).addcmul_(Ri[0], z0).addcmul_(Ri[1], z1)
        nu.add_(t[i])  # u = R_i z + t_i
        if i in chain.linear:
            nur[2].add_(pose.q[i])
        u, nu, ur, nur = nu, u, nur, ur
    rows = out.movedim(-1, 0)  # (3, ...) view, strided: written once, by a copy
    torch.mul(cs[0], ur[0], out=z).addcmul_(sc[0], ur[1])  # Rz(q_1) u
    if chain.plain_base:
        rows[:2].copy_(z)
        rows[2].copy_(ur[2])
        return out
    col = [chain.base[:3, c].view((3,) + (1,) * len(shape)) for c in range(4)]  # R_base columns, b
    torch.mul(col[2], ur[2], out=nu).addcmul_(col[0], z0).addcmul_(col[1], z1).add_(col[3])
    rows.copy_(nu)
    return out


def fk_positions(q, chain: Chain, params=None, *, chunk: int | None = None) -> torch.Tensor:
    """TCP positions for every (pose, parameter set) of the broadcast batch.

    q (..., n) rad / mm, params (..., n, 5) or None -> (..., 3) mm (`positions`).
    Without autograd or vmap on the inputs, on a CPU in float64 or float32, the compiled
    kernel runs (`fk_native`: one pass per pair, all in registers; `chunk` does not apply),
    where it is built and the batch is a grid it serves (`fk_native.grid`: e.g. q (P, n)
    with params (M, 1, n, 5), or q and params with the same batch). Otherwise work is cut
    along the largest broadcast batch dim into pieces of about `chunk` evaluations (default
    `chunk_for` the device and, for the in-place kernel, the dtype), so temporaries stay
    bounded and on a CPU in its L2 cache; the output is the full (..., 3). Without autograd
    or vmap the chunks run the in-place kernel `positions_into`; with them, `positions`.
    """
    table = chain.table
    qb = q.shape[:-1]
    pb = () if params is None else params.shape[:-2]
    batch = np.broadcast_shapes(qb, pb)  # torch.broadcast_shapes would import sympy
    total = math.prod(batch)
    plain = _plain((q, table, chain.base, chain.tool) + (() if params is None else (params,)))
    chunk = chunk or chunk_for(table.device, table.dtype if plain else None)
    if (total <= chunk or len(batch) == 0) and not plain:
        return positions(q, chain, params)
    out = torch.empty(*batch, 3, dtype=table.dtype, device=table.device)
    if plain and _native_positions(q, chain, params, out):
        return out
    if total <= chunk or len(batch) == 0:
        return positions_into(q, chain, params, out)
    # align leading dims, pick the largest batch dim to cut along
    q = q.reshape((1,) * (len(batch) - len(qb)) + q.shape)
    if params is not None:
        params = params.reshape((1,) * (len(batch) - len(pb)) + params.shape)
    dim = max(range(len(batch)), key=lambda k: batch[k])
    step = max(1, chunk * batch[dim] // total)
    if plain:  # the trig of the whole batch once, sliced per chunk
        pose, link = _PoseFactors.of(q, chain), _LinkFactors.of(chain.table, params, len(batch))

    def run(start):
        size = min(step, batch[dim] - start)
        if plain:
            _positions_into(pose.narrow(dim, start, size), link.narrow(dim, start, size), chain,
                            out.narrow(dim, start, size))
            return
        qc = q.narrow(dim, start, size) if q.shape[dim] > 1 else q
        pc = params
        if params is not None and params.shape[dim] > 1:
            pc = params.narrow(dim, start, size)
        positions(qc, chain, pc, out=out.narrow(dim, start, size))

    starts = range(0, batch[dim], step)
    workers = min(threads.workers(), len(starts)) if out.device.type == "cpu" else 1
    if workers <= 1:
        for start in starts:
            run(start)
        return out
    _map_single_threaded(run, starts, workers)
    return out


def pose_rows(q, chain: Chain) -> torch.Tensor:
    """The pose factors of the compiled kernel (`fk_native`): q (Q, n) rad / mm -> (n, 3,
    Q + fk_native.PAD) [cos q, sin q, q] per joint (cos 1 and sin 0 at a prismatic joint),
    each row padded with copies of its last value, contiguous."""
    Q = q.shape[0]
    out = torch.empty(q.shape[1], 3, Q + fk_native.PAD, dtype=q.dtype, device=q.device)
    c, s, qj = out[..., :Q].unbind(1)  # each (n, Q), rows contiguous
    qj.copy_(q.T)
    qr = qj.masked_fill(chain.prismatic[:, None], 0.0) if chain.linear else qj
    torch.cos(qr, out=c)
    torch.sin(qr, out=s)
    if Q:
        out[..., Q:] = out[..., Q - 1:Q]
    return out


def link_rows(chain: Chain, params) -> torch.Tensor:
    """The link factors of the compiled kernel (`fk_native`): params (S, n, 5) or None ->
    (n + 1, 12, S + fk_native.PAD) (S = 1 without params): per link the rows of R_i and t_i
    mm of the chain's table with the deviations (`_link_rotations`), then the start of the
    recursion u = R_(n-1) tool + t_(n-1) mm (3 of the 12 rows, per set as in
    `positions_into`); each row padded with copies of its last value, contiguous."""
    R, t = _link_rotations(chain.table, params)  # each (S, n) or (n,)
    rows = torch.stack([x for row in R for x in row] + list(t))  # (12, S, n) or (12, n)
    if rows.ndim == 2:
        rows = rows[:, None]
    tp = chain.tool[:3, 3]
    last = rows[..., -1]  # (12, S): link n - 1
    start = torch.zeros_like(rows[..., :1])  # (12, S, 1)
    for r in range(3):
        start[r, :, 0] = last[9 + r] + last[3 * r] * tp[0] + last[3 * r + 1] * tp[1] + last[3 * r + 2] * tp[2]
    rows = torch.cat([rows, start], dim=2)  # (12, S, n + 1)
    if rows.shape[1]:
        rows = torch.cat([rows, rows[:, -1:].expand(-1, fk_native.PAD, -1)], dim=1)
    return rows.permute(2, 0, 1).contiguous()


def native_frames(chain: Chain):
    """(lin (n,) int32: 1 at a prismatic joint, base (12,) [R_base rows, b mm] or None without
    a base frame) of `chain` for the compiled kernel, contiguous."""
    lin = chain.prismatic.to(torch.int32).contiguous()
    base = None if chain.plain_base else torch.cat([chain.base[:3, :3].reshape(9), chain.base[:3, 3]])
    return lin, base


def _native_positions(q, chain: Chain, params, out) -> bool:
    """`positions_into` by the compiled kernel (`fk_native`) into out (..., 3) contiguous, on
    `threads.workers()` threads; False (nothing written) where it does not serve: not built or
    turned off, not a CPU float64 / float32 tensor, a batch that is no grid."""
    lib = fk_native.available(out.device, out.dtype)
    if lib is None or not out.is_contiguous():
        return False
    batch = out.shape[:-1]
    n = chain.n
    qb = (1,) * (len(batch) + 1 - q.ndim) + tuple(q.shape[:-1])
    pb = () if params is None else tuple(params.shape[:-2])
    pb = (1,) * (len(batch) - len(pb)) + pb
    g = fk_native.grid(batch, qb, pb)
    if g is None:
        return False
    pose = pose_rows(q.reshape(-1, n), chain)
    link = link_rows(chain, None if params is None else params.reshape(-1, n, 5))
    lin, base = native_frames(chain)
    fk_native.fk_positions(lib, pose, link, lin, base, g, out.view(-1, 3), threads.workers())
    return True


def _plain(tensors) -> bool:
    """True when no tensor needs a gradient (with grad mode on) or is wrapped by
    torch.func (vmap, jvp): the in-place kernel's condition."""
    if torch.is_grad_enabled() and any(t.requires_grad for t in tensors):
        return False
    wrapped = torch._C._functorch.is_functorch_wrapped_tensor
    return not any(wrapped(t) for t in tensors)


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


def _walk(q, chain: Chain, params=None, with_origins: bool = True):
    """The frames of the chain as axis vectors, from its base through every link.

    q (..., n) rad / mm, params (..., n, 5) or None -> (zs, origins, xs, ys, ends, (X, Y, Z, o)):
    per link i (lists of n tensors (..., 3), each broadcastable to the batch) the z axis and
    origin of its input frame, its mid axes R Rz(theta) e_x and R Rz(theta) Rx(alpha) e_y,
    and its end origin; then the last frame's axes and origin (the flange, the chain's
    tool not applied). Link i maps the frame by A_i = Rz(theta) Rx(alpha) Ry(beta) with
    translation [a ct, a st, d] (`link_transforms`), one fused op per product term: on
    a CPU several times faster than products of stacked 4 x 4 matrices.
    with_origins=False: the axes only (a rotation needs no origin): origins and ends
    stay empty, the last origin is None.
    """
    table = chain.table
    n = table.shape[0]
    off, d, a, alpha, beta = _effective(table, params)  # each (..., n) or (n,)
    qr, qt = _split(q, chain)
    theta = qr + off
    if qt is not None:
        d = d + qt
    # per joint (..., 1) factors, broadcast against the (..., 3) axis vectors below
    ct, st = torch.cos(theta).unsqueeze(-1), torch.sin(theta).unsqueeze(-1)
    ca, sa = torch.cos(alpha).unsqueeze(-1), torch.sin(alpha).unsqueeze(-1)
    cb, sb = torch.cos(beta).unsqueeze(-1), torch.sin(beta).unsqueeze(-1)
    if with_origins:
        tx, ty, tz = a.unsqueeze(-1) * ct, a.unsqueeze(-1) * st, d.unsqueeze(-1)
    base = chain.base.to(theta)
    X, Y, Z, o = base[:3, 0], base[:3, 1], base[:3, 2], base[:3, 3]
    zs, origins, xs, ys, ends = [], [], [], [], []
    for i in range(n):
        c, s, ci, si, cbi, sbi = ct[..., i, :], st[..., i, :], ca[..., i, :], sa[..., i, :], cb[..., i, :], sb[..., i, :]
        x_mid = X * c + Y * s  # R Rz(theta) e_x
        y_rz = Y * c - X * s  # R Rz(theta) e_y
        y_mid = y_rz * ci + Z * si  # R Rz Rx(alpha) e_y
        z_mid = Z * ci - y_rz * si  # R Rz Rx(alpha) e_z
        zs.append(Z)
        xs.append(x_mid)
        ys.append(y_mid)
        if with_origins:
            origins.append(o)
            o = X * tx[..., i, :] + Y * ty[..., i, :] + Z * tz[..., i, :] + o
            ends.append(o)
        X, Y, Z = x_mid * cbi - z_mid * sbi, y_mid, x_mid * sbi + z_mid * cbi
    return zs, origins, xs, ys, ends, (X, Y, Z, o if with_origins else None)


def chain_jacobians(q, chain: Chain, params=None, *, tool_point=None) -> ChainJacobians:
    """Analytic TCP Jacobians w.r.t. q and the MD-H deviations (docs/paper.md eqs. 14-18).

    q (..., n) rad / mm, params (..., n, 5) or None, tool_point (..., 3) mm in the flange
    frame (None: the chain's ``tool[:3, 3]``) -> `ChainJacobians` in the world frame of
    the chain's base (``chain.local``: the joint-1 frame).
    The TCP's derivative w.r.t. the tool point is ``rotation`` (mm/mm).

    For link i with input frame F (world pose of joint i's axis) and TCP p:
    dtheta rotates about z_F through o_F, dd translates along z_F, da along the x axis
    after Rz(theta), dalpha rotates about that x axis and dbeta about the y axis after
    Rx(alpha), both through the link's end origin o_i. A revolute q_i acts as dtheta_i,
    a prismatic one as dd_i.
    """
    n = chain.table.shape[0]
    zs, origins, xs, ys, ends, (X, Y, Z, o) = _walk(q, chain, params)
    R = torch.stack([X, Y, Z], dim=-1)  # (..., 3, 3) flange rotation, columns X, Y, Z
    if tool_point is None:
        tool_point = chain.tool[:3, 3]
    tp = tool_point.to(R)
    p = o + X * tp[..., 0:1] + Y * tp[..., 1:2] + Z * tp[..., 2:3]  # R tool_point
    # (..., 3, n) per joint: its input frame's z axis and origin, the mid axes, the end origin
    z, o, x_mid, y_mid, o_end, pp = torch.broadcast_tensors(
        torch.stack(torch.broadcast_tensors(*zs), dim=-1), torch.stack(torch.broadcast_tensors(*origins), dim=-1),
        torch.stack(torch.broadcast_tensors(*xs), dim=-1), torch.stack(torch.broadcast_tensors(*ys), dim=-1),
        torch.stack(torch.broadcast_tensors(*ends), dim=-1), p.unsqueeze(-1))
    zero = torch.zeros_like(z)
    rot_z = torch.linalg.cross(z, pp - o, dim=-2)
    lever = pp - o_end
    batch = z.shape[:-2]
    dparams = torch.stack([rot_z, z, x_mid, torch.linalg.cross(x_mid, lever, dim=-2),
                           torch.linalg.cross(y_mid, lever, dim=-2)], dim=-1).reshape(*batch, 3, 5 * n)
    wparams = torch.stack([z, zero, zero, x_mid, y_mid], dim=-1).reshape(*batch, 3, 5 * n)
    dq, wq = rot_z, z
    if chain.linear:
        lin = chain.prismatic
        dq, wq = torch.where(lin, z, rot_z), torch.where(lin, zero, z)
    return ChainJacobians(p, R, dq, dparams, wq, wparams)


def param_jacobian(q, chain: Chain, params=None) -> torch.Tensor:
    """Analytic position Jacobian dP/d[params] (docs/paper.md eqs. 14-18).

    q (..., n) rad / mm, params (..., n, 5) or None -> (..., 3, 5n), columns ordered as
    ``params.reshape(..., 5n)``: joint 1's [dtheta, dd, da, dalpha, dbeta], joint 2's...
    Units: mm/rad for angle columns, mm/mm for length columns (`chain_jacobians`).
    """
    return chain_jacobians(q, chain, params).dparams


def joint_jacobian(q, chain: Chain, params=None) -> torch.Tensor:
    """Position Jacobian dP/dq. q (..., n) rad / mm -> (..., 3, n) mm/rad (revolute
    columns: z x (p - o)) or mm/mm (prismatic columns: z)."""
    return chain_jacobians(q, chain, params).dq


def outer_factors(chain: Chain, dev: torch.Tensor) -> list[torch.Tensor]:
    """Per-set trig and lengths of the perturbed links: 8 tensors (n, M).

    dev (M, n, 5) -> cos/sin of (theta_offset + dtheta), of alpha, of beta,
    then a and d, each transposed to (n, M) so that joint i's row is contiguous.
    """
    off, d, a, alpha, beta = (chain.table + dev).unbind(-1)  # each (M, n)
    return [t.T.contiguous() for t in (torch.cos(off), torch.sin(off), torch.cos(alpha), torch.sin(alpha),
                                       torch.cos(beta), torch.sin(beta), a, d)]


class OuterAngles(NamedTuple):
    """Joint values of Nc points for `outer_positions` (`outer_angles`).

    cos, sin (n, Nc): of the joint rotations (0 at a prismatic joint), joint i's row
    contiguous; travel (Nc, n) rad / mm: the joint values, read at the prismatic joints.
    """

    cos: torch.Tensor
    sin: torch.Tensor
    travel: torch.Tensor


def outer_angles(q: torch.Tensor, chain: Chain) -> OuterAngles:
    """q (Nc, n) rad / mm -> `OuterAngles` (computed once per block of points)."""
    qr = q.masked_fill(chain.prismatic, 0.0) if chain.linear else q
    return OuterAngles(torch.cos(qr).T.contiguous(), torch.sin(qr).T.contiguous(), q)


def outer_positions(q: OuterAngles, chain: Chain, F, bufs):
    """TCP positions in the joint-1 frame for (Nc points) x (Mc sets), in place.

    The outer-product layout of the backward recursion of `positions` (which
    serves any broadcast batch and autograd); this one serves the sweep's blocks,
    v <- Rz(q + off) (Rx(alpha) Ry(beta) v + [a, 0, d]), with every full-size temporary
    in one of the 7 preallocated buffers (Nc, Mc) and fused multiply-adds (addcmul):
    18 full-size operations per joint and no allocation, several times faster than the
    general kernel on a CPU. q: `outer_angles` of the Nc points; F: `outer_factors`
    sliced to the Mc sets; the tool point is the chain's. Returns three (Nc, Mc) views
    into `bufs`, mm. A prismatic joint's travel adds to d.
    """
    cq, sq = q.cos, q.sin
    tz = [None] * chain.n
    for i in chain.linear:
        tz[i] = q.travel[:, i]
    tool_point = chain.tool[:3, 3]
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
