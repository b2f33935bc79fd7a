"""The signed residual component along a variable's fitted dependence (what the plots draw).

The residual *length* hides a dependence whose sign flips: backlash moves the TCP by +d
for one approach direction and -d for the other, with the same length. For each variable
v of `torchcal.diagnosis.unexplained.variables`, `signed_components` fits the residual
by the same smooth model as `unexplained` (a joint-angle error and a TCP offset that vary
with v: columns ``phi_b(v) * [dP/dq, I3]``, `unexplained.basis`), here once on all rows
by least squares, and projects each residual on the direction of that dependence:

- the columns ``[dP/dq, I3]`` are scaled to unit RMS TCP displacement over the rows, so
  the fitted coefficients c_b ((n + 3,), one per basis function b) are comparable in mm;
- w = the first principal direction of the c_b about their mean (weighted by how many
  rows each basis function carries): the way the fitted error changes along v;
  signed so that the fit at the largest v minus the fit at the smallest has w >= 0;
- at row i the direction is u_i = D_i w (3,) (D_i the scaled columns at that pose), and
  the component is ``r_i . u_i / |u_i|`` in mm (0 where u_i = 0).

So for backlash the two approach directions fall on either side of zero; for a smooth
dependence (compliance, a coupling, drift) the component follows the fitted curve.
"""

from __future__ import annotations

import numpy as np
import torch

from torchcal.diagnosis.unexplained import basis, smooth_columns, tcp_columns, variables
from torchcal.measurements import Measurements
from torchcal.robots.robot import Robot


def signed_components(robot: Robot, m: Measurements, residuals) -> dict[str, np.ndarray]:
    """{variable: (N,) mm} the signed component of residuals (N, 3) mm along the fitted
    dependence on each variable of `unexplained.variables(robot, m)` (module doc)."""
    r = (residuals.detach().cpu().to(torch.float64).numpy(force=True) if isinstance(residuals, torch.Tensor)
         else np.asarray(residuals, dtype=np.float64)).reshape(-1, 3)
    D = tcp_columns(robot, m.q)  # (N, 3, n + 3)
    D = D / (D ** 2).sum(1).mean(0).sqrt().clamp_min(1e-300)  # unit RMS TCP displacement per column
    out = {}
    for name, v in variables(robot, m).items():
        H = basis(v)  # (N, b), columns in increasing v
        X = smooth_columns(torch.from_numpy(H), D).numpy(force=True)
        c = np.linalg.lstsq(X, r.reshape(-1), rcond=1e-10)[0].reshape(H.shape[1], -1)  # (b, n + 3)
        weight = H.sum(0)
        centred = (c - (weight[:, None] * c).sum(0) / weight.sum()) * np.sqrt(weight)[:, None]
        w = np.linalg.svd(centred, full_matrices=False)[2][0]  # (n + 3,)
        if (c[-1] - c[0]) @ w < 0:
            w = -w
        u = D.numpy(force=True) @ w  # (N, 3)
        length = np.linalg.norm(u, axis=1)
        out[name] = np.where(length > 0, (r * u).sum(1) / np.where(length > 0, length, 1.0), 0.0)
    return out
