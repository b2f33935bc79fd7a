"""Several measured points per pose (one tool offset each) and measured orientation."""

from __future__ import annotations

import math

import pytest
import torch

import torchcal
from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.effects import make_context
from torchcal.robots.poses import random_poses

OFFSETS = torch.tensor([[60.0, 0.0, 40.0], [-30.0, 52.0, 45.0], [-30.0, -52.0, 50.0]], dtype=torch.float64)


@pytest.fixture(scope="module")
def truth(mdh_deviations):
    """ur5e with realistic MD-H deviations, three reflectors, and a periodic gear error on
    joints 2 and 3 that the fitted (geometric) model does not contain."""
    rob = torchcal.robot("ur5e")
    model = CalibrationModel(rob, ["gear_periodic:2,3", "tool_offset"], points=[1, 2, 3])
    g = torch.Generator().manual_seed(7)
    th = model.zeros()
    th[: 5 * rob.n] = mdh_deviations(rob, g).flatten()
    th[model.slices[1]] = (torch.rand(16, generator=g, dtype=torch.float64) * 2 - 1) * math.radians(0.004)
    th[model.slices[2]] = OFFSETS.flatten()
    return rob, model, th


def _rows(truth, n_poses, seed, points):
    rob, model, th = truth
    q = random_poses(rob, n_poses, seed).repeat_interleave(len(points), 0)
    pt = torch.tensor(points * n_poses)
    ctx = make_context(rob, q, point=pt)
    g = torch.Generator().manual_seed(seed + 100)
    return q, pt, model.predict(th, ctx) + 0.02 * torch.randn(q.shape[0], 3, generator=g, dtype=torch.float64)


def _fit(truth, q, pt, xyz, points):
    rob = truth[0]
    model = CalibrationModel(rob, ["tool_offset"], points=points)
    return fit(model, make_context(rob, q, point=pt), xyz)


def _error_at_fresh_poses(truth, res, point):
    """RMS distance fitted model - truth (noise-free) for `point` at 50 fresh poses, mm."""
    rob, model, th = truth
    q = random_poses(rob, 50, 99)
    pt = torch.full((50,), point)
    true = model.predict(th, make_context(rob, q, point=pt))
    fitted = res.model.predict(res.theta, make_context(rob, q, point=pt if res.model.points else None))
    return float((fitted - true).norm(dim=-1).pow(2).mean().sqrt())


def test_three_points_per_pose_recover_offsets_and_geometry(truth):
    q3, pt3, x3 = _rows(truth, 30, 1, [1, 2, 3])
    res3 = _fit(truth, q3, pt3, x3, [1, 2, 3])
    # each point's offset: the distances between the reflectors are identifiable
    t = res3.theta[res3.model.slices[1]].view(3, 3) + res3.model.robot.tool[:3, 3]
    for a, b in ((0, 1), (0, 2), (1, 2)):
        assert float((t[a] - t[b]).norm()) == pytest.approx(float((OFFSETS[a] - OFFSETS[b]).norm()), abs=0.05)
    # geometry as well as one point per pose with 3x the poses
    for k in (1, 2, 3):
        q1, pt1, x1 = _rows(truth, 90, 2, [k])
        res1 = _fit(truth, q1, pt1, x1, [k])
        e3, e1 = _error_at_fresh_poses(truth, res3, k), _error_at_fresh_poses(truth, res1, k)
        assert e3 < 0.1 and e3 <= 1.5 * e1 + 0.01, (k, e3, e1)


def test_multiple_points_need_a_point_column(truth):
    from torchcal.errors import InputError

    rob = truth[0]
    model = CalibrationModel(rob, ["tool_offset"], points=[1, 2])
    q = random_poses(rob, 5, 0)
    with pytest.raises(InputError, match="no point column"):
        model.check_context(make_context(rob, q))
    with pytest.raises(InputError, match="point id 7"):
        model.check_context(make_context(rob, q, point=torch.tensor([1, 2, 7, 1, 2])))


def test_orientation_weighted_by_sigma(truth):
    """Measured orientation: a tiny weight fits positions as the position-only fit does; the stated
    weight fits the orientation to its noise and recovers the tool rotation."""
    from torchcal.rotations import fixed_xyz_to_matrix

    rob, tm, th = truth
    q = random_poses(rob, 40, 3)
    ctx = make_context(rob, q, point=torch.ones(40, dtype=torch.long))
    xyz = tm.predict(th, ctx) + 0.02 * torch.randn(40, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    Rt = fixed_xyz_to_matrix(torch.deg2rad(torch.tensor([1.0, -2.0, 90.0], dtype=torch.float64)))
    noise = fixed_xyz_to_matrix(torch.deg2rad(0.005 * torch.randn(40, 3, generator=torch.Generator().manual_seed(2),
                                                                     dtype=torch.float64)))
    R = tm.predict_rotation(th, ctx) @ Rt @ noise
    model = CalibrationModel(rob, ["tool_offset"])
    c = make_context(rob, q)
    pos = fit(model, c, xyz)
    weak = fit(model, c, xyz, rotation=R, sigma_deg=1e6)
    assert weak.rms_mm == pytest.approx(pos.rms_mm, rel=0.02)
    full = fit(model, c, xyz, rotation=R)
    assert full.orientation["rms_deg"] < 0.02
    assert full.orientation["weight_mm_per_rad"] == pytest.approx(0.01 / math.radians(0.01))
    err = full.orientation["tool_rotation"].T @ Rt
    assert math.degrees(math.acos(min(1.0, (float(torch.trace(err)) - 1) / 2))) < 0.1
