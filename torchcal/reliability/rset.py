"""Non-probabilistic reliability of a positioning error: eta (eq. 23) and R_set (eq. 24).

Both functions take ``allowed`` and ``actual`` as pairs ``(lower, upper)``:

- ``actual = (s_l, s_u)``: the interval of the actual error s (an `Interval` also works),
  numbers or tensors, broadcast against each other and against ``allowed``.
- ``allowed = (L, U)``: the allowed region of the error, ``L <= s <= U``. Each limit is

  * a number or tensor: a *crisp* limit;
  * an `Interval`: an *interval* limit, known only to lie in ``[l, u]`` (the allowed
    error r of docs/paper.md eqs. 20-22 when it is itself uncertain);
  * ``None`` or an infinity: no limit on that side (no failure mode there).

  Per axis, allowed +-a is ``(-a, a)``; for the distance error, allowed ``[0, D]`` is
  ``(0, D)`` in `r_set` (a distance is never negative, so its lower limit 0 never fails).
  For `eta` pass ``(None, D)`` for a distance (see `eta` for why).

eta (eq. 23), per failure mode, with M = g(r, s) the limit state::

    upper limit U:  M = U - s,   eta_U = (U^c - s^c) / (U^r + s^r)
    lower limit L:  M = s - L,   eta_L = (s^c - L^c) / (L^r + s^r)
    eta = min(eta_L, eta_U)      (a series system: the weaker mode decides)

eta > 1: every error in the actual interval is allowed for every admissible limit
(always safe); eta < -1: some mode fails for every combination (always failing);
otherwise undetermined. eta = 1 exactly means the actual interval touches a limit.

R_set (eq. 24) is the safe share of the actual interval. Our reading of "the fully safe
part plus half the undetermined part":

- split the actual interval [s_l, s_u] by the limits: values that satisfy every
  admissible limit are *fully safe* (weight 1), values that violate every admissible
  limit are *failing* (weight 0), values between the ends of an interval limit
  ``[l, u]`` are *undetermined*;
- an undetermined value s is credited with the share of admissible limits it satisfies,
  ``w(s) = (u - s) / (u - l)`` for an upper limit (a linear ramp from 1 to 0);
- ``R_set = (1 / (s_u - s_l)) * integral of w(s) over [s_l, s_u]``.

Where the whole undetermined zone lies inside the actual interval, the ramp integrates
to exactly half its length: R_set = (fully safe length + 1/2 undetermined length) /
total length, the sentence of the paper. In general it is the area formula of Wang, Qiu
& Elishakoff (2008) for two independent intervals r in [r_l, r_u], s in [s_l, s_u]:
R_set = P(r > s) = area of {r > s} in the rectangle / area of the rectangle (see
`interference`). With crisp limits there is no undetermined part and
R_set = |[s_l, s_u] inside [L, U]| / (s_u - s_l); for one crisp limit this equals
clip((1 + eta) / 2, 0, 1).

Table 3 of the paper (allowed distance [0, 2.5] mm, actual [0, s^u]): crisp,
R_set = 2.5 / s^u for s^u > 2.5 -> 0.984, 0.97, 0.867, 0.994 and 1, 1. Two rows of the
table (s^u = 3.244466201 -> 0.7 and 3.287477271 -> 0.685) match no formula that also
matches the other six (2.5 / s^u gives 0.771 and 0.760; the interval-limit readings of
[0, 2.5] give 0.385 and 0.380 and already fail the other rows): we treat them as errors
in the paper (tests/test_rset.py checks both statements).

A degenerate actual interval (s_l == s_u) gets the weight of its single value.
Units: any, the same for both arguments (mm here). Inputs stay on their device.
"""

from __future__ import annotations

import math

import torch

from torchcal.errors import InputError
from torchcal.reliability.interval import Interval


def _float(x) -> tuple[torch.Tensor, bool]:
    """(tensor, weak): a tensor stays (made floating); numbers and lists become float64
    tensors marked weak, which take the dtype of the other arguments (as torch does)."""
    if isinstance(x, torch.Tensor):
        return (x if x.is_floating_point() else x.to(torch.float64)), False
    return torch.as_tensor(x, dtype=torch.float64), True


def _as_limit(x, name: str, default: float):
    """A limit -> (lo, hi, weak) tensors; crisp: lo == hi; None -> (default, default)."""
    if x is None:
        t = torch.tensor(default, dtype=torch.float64)
        return t, t, True
    if isinstance(x, Interval):
        if not (torch.isfinite(x.lower).all() and torch.isfinite(x.upper).all()):
            raise InputError(f"{name}: an interval limit must have finite bounds (use None for no limit)")
        return x.lower, x.upper, False
    if isinstance(x, (tuple, list)):
        raise InputError(f"{name}: an interval limit must be an Interval, got a {type(x).__name__}; "
                         f"a crisp limit is a number or tensor")
    t, weak = _float(x)
    if bool(torch.isnan(t).any()):
        raise InputError(f"{name}: limit must not be NaN")
    return t, t, weak


def _pair(x, name: str):
    """actual (lower, upper) or Interval -> two float tensors and whether both are weak."""
    if isinstance(x, Interval):
        return x.lower, x.upper, False
    try:
        lo, hi = x
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a pair (lower, upper) or an Interval, got {type(x).__name__}") from None
    (lo, wlo), (hi, whi) = _float(lo), _float(hi)
    if not (torch.isfinite(lo).all() and torch.isfinite(hi).all()):
        raise InputError(f"{name}: bounds must be finite")
    if bool((hi < lo).any()):
        raise InputError(f"{name}: lower must be <= upper, got lower {lo.max().item()} > upper {hi.min().item()}"
                         if lo.numel() == 1 and hi.numel() == 1 else f"{name}: lower must be <= upper everywhere")
    return lo, hi, wlo and whi


def _prepare(allowed, actual):
    try:
        L, U = allowed
    except (TypeError, ValueError):
        raise InputError(f"allowed: expected a pair (lower_limit, upper_limit), got {type(allowed).__name__}") from None
    sl, su, weak_s = _pair(actual, "actual")
    ll, lu, weak_l = _as_limit(L, "allowed lower limit", -math.inf)
    ul, uu, weak_u = _as_limit(U, "allowed upper limit", math.inf)
    # dtype: that of the tensors given; plain numbers follow them (float64 if all are numbers)
    strong = [t for t, weak in ((sl, weak_s), (su, weak_s), (ll, weak_l), (ul, weak_u)) if not weak]
    dtype = torch.float64
    if strong:
        dtype = strong[0].dtype
        for t in strong[1:]:
            dtype = torch.promote_types(dtype, t.dtype)
    dev = (strong[0] if strong else sl).device
    sl, su, ll, lu, ul, uu = (t.to(device=dev, dtype=dtype) for t in (sl, su, ll, lu, ul, uu))
    sl, su, ll, lu, ul, uu = torch.broadcast_tensors(sl, su, ll, lu, ul, uu)
    if bool((ll == math.inf).any()) or bool((uu == -math.inf).any()):
        raise InputError("allowed: a lower limit of +inf or an upper limit of -inf allows nothing")
    if bool((lu > ul).any()):
        raise InputError("allowed: the lower limit must lie below the upper limit "
                         "(its largest admissible value <= the upper limit's smallest)")
    return sl, su, ll, lu, ul, uu


def _mode_eta(num, den):
    """num / den with den >= 0; den == 0 (crisp limit, point error): +-inf, or 1 on the limit."""
    safe_den = torch.where(den > 0, den, torch.ones_like(den))
    out = torch.where(den > 0, num / safe_den, torch.sign(num) * math.inf)
    return torch.where((den == 0) & (num == 0), torch.ones_like(out), out)


def eta(allowed, actual) -> torch.Tensor:
    """Non-probabilistic reliability index (docs/paper.md eq. 23), elementwise.

    Args:
        allowed: ``(L, U)``, each a number/tensor (crisp), an `Interval` or None.
        actual: ``(s_l, s_u)`` or an `Interval`, the actual error interval.

    Returns:
        tensor of the broadcast shape: ``min(eta_L, eta_U)``; a side without a limit
        contributes +inf. For a distance error pass ``(None, D)``: with ``(0, D)`` the
        lower mode of an interval ``[0, s^u]`` touches its limit and has eta_L = 1
        exactly, which caps eta at 1 (correct, but it hides how safe the upper mode is).

    Example::

        >>> eta((None, 2.5), (0.0, 2.0))   # (2.5 - 1) / (0 + 1)
        tensor(1.5000, dtype=torch.float64)
    """
    sl, su, ll, lu, ul, uu = _prepare(allowed, actual)
    sc, sr = 0.5 * (sl + su), 0.5 * (su - sl)
    inf = torch.full_like(sc, math.inf)
    has_u = torch.isfinite(uu)
    has_l = torch.isfinite(ll)
    uc = torch.where(has_u, 0.5 * (ul + uu), torch.zeros_like(sc))
    ur = torch.where(has_u, 0.5 * (uu - ul), torch.zeros_like(sc))
    lc = torch.where(has_l, 0.5 * (ll + lu), torch.zeros_like(sc))
    lr = torch.where(has_l, 0.5 * (lu - ll), torch.zeros_like(sc))
    eta_u = torch.where(has_u, _mode_eta(uc - sc, ur + sr), inf)
    eta_l = torch.where(has_l, _mode_eta(sc - lc, lr + sr), inf)
    return torch.minimum(eta_l, eta_u)


def _segment(a, b, lo, hi):
    """Clipped segment [max(a, lo), min(b, hi)] -> (x0, x1, length >= 0), inf-safe."""
    x0, x1 = torch.maximum(a, lo), torch.minimum(b, hi)
    length = (x1 - x0).clamp_min(0)
    ok = length > 0
    return torch.where(ok, x0, a), torch.where(ok, x1, a), length


def r_set(allowed, actual) -> torch.Tensor:
    """Non-probabilistic set reliability R_set (docs/paper.md eq. 24), elementwise, in [0, 1].

    Args:
        allowed: ``(L, U)``, each a number/tensor (crisp), an `Interval` or None.
        actual: ``(s_l, s_u)`` or an `Interval`.

    Returns:
        tensor of the broadcast shape: the safe share of ``[s_l, s_u]``, the undetermined
        part weighted by the share of admissible limits it satisfies (module docstring).

    Example::

        >>> r_set((0.0, 2.5), (0.0, 2.541205104))   # docs/paper.md Table 3, row 1
        tensor(0.9838, dtype=torch.float64)
    """
    sl, su, ll, lu, ul, uu = _prepare(allowed, actual)
    # w(s): 0 below ll, ramp up on [ll, lu], 1 on [lu, ul], ramp down on [ul, uu], 0 above;
    # integrate it piece by piece over [sl, su] (each piece >= 0: no cancellation)
    _, _, safe = _segment(sl, su, lu, ul)  # fully safe part
    x0, x1, len_up = _segment(sl, su, ll, lu)  # undetermined, lower limit
    wl = torch.where(len_up > 0, lu - ll, torch.ones_like(sl))
    safe = safe + torch.where(len_up > 0, len_up * (x0 + x1 - 2 * torch.where(len_up > 0, ll, x0)) / (2 * wl), 0.0)
    x0, x1, len_dn = _segment(sl, su, ul, uu)  # undetermined, upper limit
    wu = torch.where(len_dn > 0, uu - ul, torch.ones_like(sl))
    safe = safe + torch.where(len_dn > 0, len_dn * (2 * torch.where(len_dn > 0, uu, x1) - x0 - x1) / (2 * wu), 0.0)
    length = su - sl
    r_interval = safe / torch.where(length > 0, length, torch.ones_like(length))
    # a point error: the weight of its value (closed limits: on the limit counts as safe)
    one = torch.ones_like(sl)
    wu_all, wl_all = uu - ul, lu - ll
    w_u = torch.where(torch.isfinite(wu_all) & (wu_all > 0),
                      1 - ((sl - ul) / torch.where(wu_all > 0, wu_all, one)).clamp(0, 1), (sl <= uu).to(sl.dtype))
    w_l = torch.where(torch.isfinite(wl_all) & (wl_all > 0),
                      ((sl - ll) / torch.where(wl_all > 0, wl_all, one)).clamp(0, 1), (sl >= ll).to(sl.dtype))
    return torch.where(length > 0, r_interval, w_u * w_l).clamp(0.0, 1.0)


def interference(strength, stress) -> torch.Tensor:
    """P(r > s) for independent intervals r (allowed, 'strength') and s (actual, 'stress').

    The area formula of Wang, Qiu & Elishakoff (2008): the area of {r > s} inside the
    rectangle [r_l, r_u] x [s_l, s_u] over the rectangle's area (a crisp r or s is the
    limit of a thin rectangle). Equal to ``r_set((None, Interval(r_l, r_u)), (s_l, s_u))``.
    strength, stress: pairs (lower, upper) or Intervals, broadcast.
    """
    rl, ru, _ = _pair(strength, "strength")
    return r_set((None, Interval(rl, ru)), stress)
