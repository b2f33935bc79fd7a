"""The plausibility prior's rows and their strength (`torchcal.calibration.plausibility`
gives the plausible scales s_i).

The fit appends one residual row ``rho * theta_i / s_i`` per parameter with a finite
scale (a Gaussian prior theta_i ~ N(0, s_i^2) for measurement rows of per-axis scale
rho), so the prior's information in the fit's row units is ``rho^2 / s_i^2``:

- `prior_factors`: the rows' factors ``rho / s_i`` (P,), 0 where a parameter has no scale;
- `prior_strength`: rho, the per-axis RMS of the position residual (N, 3) mm of the fit
  itself; of a robust fit, over the inlier rows only (`torchcal.calibration.robust.inliers`),
  so gross rows do not inflate it; at least 1e-12 mm;
- `rho_settled`: the fit re-solves while rho moves by more than `RHO_RTOL` (10 %), and
  stops once the residual is below `RHO_EXACT` (a fit to rounding needs no prior).
"""

from __future__ import annotations

import torch

from torchcal.calibration.robust import inliers

RHO_EXACT = 1e-9  # mm: a residual RMS below it is a fit to rounding (the prior is left out)
RHO_RTOL = 0.1  # relative change of rho below which the fit and its prior agree


def inverse_scales(scales: torch.Tensor) -> torch.Tensor:
    """(P,) 1 / s_i for the plausible scales (P,) (inf: no prior), 0 where s_i is infinite."""
    return torch.where(torch.isfinite(scales), 1.0 / scales, torch.zeros_like(scales))


def prior_factors(rho: float, scales: torch.Tensor) -> torch.Tensor:
    """(P,) the prior rows' factors rho / s_i (row i is factor_i * theta_i, mm), 0 where
    s_i is infinite; rho mm, scales (P,) in the parameters' units."""
    return rho * inverse_scales(scales)


def prior_strength(resid: torch.Tensor, robust: bool = False) -> float:
    """rho mm: per-axis RMS of the position residual resid (N, 3) mm, over the inlier rows
    only when `robust`; at least 1e-12."""
    r = resid.detach()
    if robust:
        r = r[inliers(r.norm(dim=-1))]
    return max(float(r.pow(2).mean().sqrt()), 1e-12)


def rho_settled(new: float, rho: float) -> bool:
    """True when the prior's strength `new` mm agrees with the `rho` mm the fit used
    (within RHO_RTOL relative) or the fit is exact (new < RHO_EXACT)."""
    return abs(new - rho) <= RHO_RTOL * rho or new < RHO_EXACT
