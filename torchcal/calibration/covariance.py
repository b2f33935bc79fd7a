"""Parameter uncertainty of a fit and its propagation to the TCP.

Covariance of the fitted parameters (linearised at the solution, identified columns only):

- every pose measured once: ``C = s^2 (J^T W J)^-1``, ``s^2 = sum w r^2 / (R - K)`` for R
  residual rows (3N for positions, 6N with orientations) and K identified parameters
  (`row_covariance`);
- poses measured more than once (repeated pose ids): *pose-level*. The residual of row k
  of pose g is modelled as ``b_g + e_gk``: a pose-level error b (what the model misses at
  that pose, shared by its repeats, variance sb2 per axis) plus measurement noise e
  (variance se2). Repeats do not average b away, so treating the 3N rows as independent
  would understate C by up to the number of repeats. With ``S_g = sum_k J_gk`` (3, K):

      C = B (sb2 sum_g S_g^T S_g + se2 J^T J) B,    B = (J^T J)^-1

  se2 from the scatter of the rows about their pose means (3(N - G) degrees of
  freedom), sb2 = max(0, (sum_g n_g |rbar_g|^2 / (3G - K) - se2) / (N / G)). For equal
  repeats this is exactly the ordinary covariance of a fit to the G pose means, and with
  no repeats it reduces to the line above. Intervals use Student's t with 3G - K
  (pose-level) or 3N - K degrees of freedom.

With the plausibility prior (the fit's rows ``rho theta_i / s_i``,
`torchcal.calibration.plausibility`) the covariance is the posterior one: with
``Pp = diag(rho^2 / s_i^2)`` (the prior's information in the fit's row units) and
``B = (J^T W J + Pp)^-1``,

    C = B (meat + s^2 Pp) B

where meat is ``s^2 J^T W J`` (rows) or the pose-level meat above and s^2 the fit's
per-axis residual variance (pose-level: sb2 + se2). The first term is the scatter of the
estimate over the noise, the second the part the prior leaves undetermined (the
estimate's bias towards zero, averaged over the prior). In the rows case this is exactly
``s^2 (J^T W J + Pp)^-1``, the Gaussian posterior covariance scaled as the fit's sigma:
a parameter the data determine keeps its data-only standard error, one only the prior
pins gets about its plausible size s_i instead of a huge data-only figure or zero.

`tcp_covariance` propagates C to positions: ``Sigma_i = J_i C J_i^T`` (3, 3) per pose;
``tcp_sigma`` is ``sqrt(trace Sigma_i)``, the 1-sigma (RMS) length of the 3-D position
error due to the parameter uncertainty, mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class ParameterCovariance:
    """cov: (P, P) in the parameters' units (zero rows/columns where held); dof: degrees of
    freedom of the variance estimate; sigma_mm: sqrt of the per-axis residual variance
    (pose-level: sb2 + se2); method: 'rows' or 'pose-level'; noise_mm / pose_mm: sqrt(se2),
    sqrt(sb2) (pose-level only, else None)."""

    cov: torch.Tensor
    dof: int
    sigma_mm: float
    method: str
    noise_mm: float | None = None
    pose_mm: float | None = None

    @property
    def std(self) -> torch.Tensor:
        """(P,) standard errors."""
        return torch.diagonal(self.cov).clamp_min(0).sqrt()

    def interval95(self, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(lower, upper) (P,) 95 % confidence interval, Student's t with `dof`."""
        from torchcal.statistics import t_quantile

        h = t_quantile(0.975, max(self.dof, 1)) * self.std
        return theta - h, theta + h

    def to_dict(self, names) -> dict:
        """JSON form: identified parameters only (nonzero variance or free)."""
        idx = torch.nonzero(torch.diagonal(self.cov) > 0).flatten().tolist()  # one transfer, not one per parameter
        sub = self.cov[idx][:, idx]
        return {"method": self.method, "dof": self.dof, "sigma_mm": self.sigma_mm,
                "noise_mm": self.noise_mm, "pose_mm": self.pose_mm,
                "parameters": [names[i] for i in idx], "matrix": sub.tolist()}


def parameter_covariance(J: torch.Tensor, resid: torch.Tensor, free: torch.Tensor, pose=None,
                         weights=None, prior=None) -> ParameterCovariance:
    """Covariance of the fitted parameters.

    J: (N, 3, P) position Jacobian at the solution (mm per unit); resid: (N, 3) mm;
    free: (P,) bool identified parameters; pose: (N,) int pose ids (None: all distinct);
    weights: (N,) robust row weights (None: ones); prior: (P,) the prior rows' factors
    ``rho / s_i`` (0 where no prior; None: no prior), giving the posterior covariance
    (module doc).
    """
    N, _, P = J.shape
    K = int(free.sum())
    cov = torch.zeros(P, P, dtype=J.dtype, device=J.device)
    w = torch.ones(N, dtype=J.dtype, device=J.device) if weights is None else weights.to(J)
    sw = w.sqrt()
    Jf = J[:, :, free] * sw[:, None, None]  # (N, 3, K)
    r = resid * sw[:, None]
    A = Jf.reshape(-1, K)
    if K == 0:
        return ParameterCovariance(cov, max(3 * N, 1), 0.0, "rows")
    groups = None
    if pose is not None:
        _, groups = torch.unique(torch.as_tensor(pose, device=J.device), return_inverse=True)
    G = N if groups is None else int(groups.max()) + 1
    if G == N:
        return row_covariance(J.reshape(-1, P), resid.reshape(-1), free, weights=w.repeat_interleave(3),
                              prior=prior)
    Pp = torch.zeros(K, K, dtype=J.dtype, device=J.device) if prior is None else \
        torch.diag(torch.as_tensor(prior, dtype=J.dtype, device=J.device)[free] ** 2)
    Binv = torch.linalg.pinv(A.T @ A + Pp)
    n_g = torch.zeros(G, dtype=J.dtype, device=J.device).index_add_(0, groups, torch.ones_like(w))
    rbar = torch.zeros(G, 3, dtype=J.dtype, device=J.device).index_add_(0, groups, r) / n_g[:, None]
    within = float(((r - rbar[groups]) ** 2).sum())
    se2 = within / max(3 * (N - G), 1)
    dof = max(3 * G - K, 1)
    between = float((n_g[:, None] * rbar ** 2).sum()) / dof
    sb2 = max(0.0, (between - se2) / (N / G))
    S = torch.zeros(G, 3, K, dtype=J.dtype, device=J.device).index_add_(0, groups, Jf).reshape(-1, K)
    meat = sb2 * (S.T @ S) + se2 * (A.T @ A)
    cov_f = Binv @ (meat + (sb2 + se2) * Pp) @ Binv
    out = dict(dof=dof, sigma_mm=(sb2 + se2) ** 0.5, method="pose-level",
               noise_mm=se2 ** 0.5, pose_mm=sb2 ** 0.5)
    idx = torch.nonzero(free).flatten()
    cov[idx[:, None], idx[None, :]] = 0.5 * (cov_f + cov_f.T)
    return ParameterCovariance(cov, **out)


def row_covariance(J: torch.Tensor, r: torch.Tensor, free: torch.Tensor, weights=None,
                   prior=None) -> ParameterCovariance:
    """Covariance of independent residual rows: ``C = s^2 (J^T W J + Pp)^-1`` on the free
    columns, ``s^2 = sum w r^2 / (R - K)`` (module doc).

    J: (R, P) residual Jacobian at the solution; r: (R,) residuals (mm or mm-equivalent);
    free: (P,) bool identified parameters (K of them); weights: (R,) row weights (None:
    ones); prior: (P,) the prior rows' factors (None: no prior). dof = max(R - K, 1).
    """
    R, P = J.shape
    K = int(free.sum())
    sw = torch.ones(R, dtype=J.dtype, device=J.device) if weights is None else weights.to(J).sqrt()
    dof = max(R - K, 1)
    s2 = float(((r * sw) ** 2).sum()) / dof
    cov = torch.zeros(P, P, dtype=J.dtype, device=J.device)
    if K:
        A = J[:, free] * sw[:, None]  # W^(1/2) J
        Pp = 0.0 if prior is None else torch.diag(torch.as_tensor(prior, dtype=J.dtype, device=J.device)[free] ** 2)
        C = s2 * torch.linalg.pinv(A.T @ A + Pp)
        idx = torch.nonzero(free).flatten()
        cov[idx[:, None], idx[None, :]] = 0.5 * (C + C.T)
    return ParameterCovariance(cov, dof, math.sqrt(s2), "rows")


def tcp_covariance(J: torch.Tensor, cov: torch.Tensor) -> torch.Tensor:
    """Sigma (N, 3, 3) mm^2 of the predicted TCP positions: J (N, 3, P), cov (P, P)."""
    return J @ cov @ J.transpose(-1, -2)


def tcp_sigma(J: torch.Tensor, cov: torch.Tensor) -> torch.Tensor:
    """(N,) mm: sqrt(trace J_i C J_i^T), the RMS length of the 3-D position error."""
    return torch.einsum("nip,pq,niq->n", J, cov, J).clamp_min(0).sqrt()
