"""The nominal robot's frame fit (torchcal.calibration.checks.frame_fit) against the fit it
replaces, and its lower bound."""

from __future__ import annotations

import dataclasses

import torch

from torchcal.calibration.checks.verdict import GROSS_MM


def test_frame_fit_is_the_fit_it_replaces(ur10_series_d):
    """`in_frame`'s frame fit without the chain in its loop (`frame_fit`) lands where `fit`
    with the same start and free set does, on a refused file (q2 and q3 swapped: a
    large-residual fit of tens of iterations) and on the file as taken."""
    from torchcal.calibration.checks.frame_fit import frame_bound_mm, frame_fit
    from torchcal.calibration.fit import fit
    from torchcal.calibration.model import CalibrationModel
    from torchcal.calibration.registration import frame_slices, register_frame
    from torchcal.effects import context_of

    rob, m, _ = ur10_series_d
    part = dataclasses.replace(m.subset(slice(0, 120, 2)), q_prev=None)
    for q in (part.q, part.q[:, [0, 2, 1, 3, 4, 5]]):
        mm = dataclasses.replace(part, q=q)
        model = CalibrationModel.for_measurements(rob, ["base_frame", "tool_offset"], mm)
        ctx = context_of(rob, mm)
        free = torch.zeros(model.n_params, dtype=torch.bool)
        for sl in frame_slices(model, True):
            free[sl] = True
        start, _ = register_frame(model, ctx, mm.xyz)
        quick = frame_fit(model, ctx, mm.xyz, start, free)
        res = fit(model, ctx, mm.xyz, theta0=start, free=free, register=False, max_length_mm=None, max_angle_deg=None)
        rms = float(res.residuals.norm(dim=-1).pow(2).mean().sqrt())
        assert quick is not None
        assert torch.allclose(quick, mm.xyz - res.residuals, rtol=0, atol=1e-6), (quick - mm.xyz + res.residuals).abs().max()
        assert abs(float((quick - mm.xyz).norm(dim=-1).pow(2).mean().sqrt()) - rms) <= 1e-9 * max(rms, 1.0)
        bound = frame_bound_mm(model, mm)
        assert 0.0 < bound <= rms * (1 + 1e-9), (bound, rms)
        assert (bound > GROSS_MM) == (rms > GROSS_MM), (bound, rms)  # as taken: within; swapped: beyond
