"""Order measurement poses so that the joint moves stay short.

Distance between poses: the largest joint move, max_j |q_a,j - q_b,j| (rad): the time of a
synchronous point-to-point move. The tour starts at a given pose (all-zero joints, the
robot's home) and is open: nearest neighbour, then 2-opt (reverse a segment while the
total shrinks).
"""

from __future__ import annotations

import numpy as np
import torch


def _dist(q: torch.Tensor) -> torch.Tensor:
    return (q[:, None, :] - q[None, :, :]).abs().amax(-1)


def path_length(q: torch.Tensor, start=None) -> float:
    """Total of the largest joint move along rows q (N, n) rad, from `start` (n,) if given."""
    if start is not None:
        q = torch.cat([start.reshape(1, -1).to(q), q])
    return float((q[1:] - q[:-1]).abs().amax(-1).sum())


def order_poses(q: torch.Tensor, start=None, max_passes: int = 50) -> torch.Tensor:
    """Permutation (N,) of rows q (N, n) rad: a short open tour from `start` (default zeros)."""
    N = q.shape[0]
    start = torch.zeros(q.shape[1], dtype=q.dtype) if start is None else start.to(q)
    pts = torch.cat([start.reshape(1, -1), q])
    D = _dist(pts).numpy()
    tour, left = [0], set(range(1, N + 1))
    while left:
        last = tour[-1]
        nxt = min(left, key=lambda j: D[last, j])
        tour.append(nxt)
        left.remove(nxt)
    tour = np.array(tour)
    for _ in range(max_passes):  # 2-opt on the open path; node 0 (start) stays first
        better = False
        for i in range(1, N):
            a, b = tour[i - 1], tour[i]
            c = tour[i:]  # candidate segment ends j in i..N
            d_next = np.append(D[tour[i:N], tour[i + 1:N + 1]], 0.0)
            nxt = np.append(tour[i + 1:], -1)
            old = D[a, b] + d_next
            new = D[a, c] + np.where(nxt >= 0, D[b, np.maximum(nxt, 0)], 0.0)
            gain = old - new
            j = int(gain.argmax())
            if gain[j] > 1e-12:
                tour[i:i + j + 1] = tour[i:i + j + 1][::-1].copy()
                better = True
        if not better:
            break
    return torch.as_tensor(tour[1:] - 1)
