"""`determination(..., partners=False)`: which parameters and why, without the partner search."""

import torch

import torchcal
from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.plausibility import determination
from torchcal.effects import context_of
from torchcal.simulation.virtual_robot import VirtualRobot, random_poses

ROBOT = torchcal.robot("kr1000titan")


def test_without_partners_the_same_parameters_and_reasons():
    g = torch.Generator().manual_seed(5)
    q = random_poses(ROBOT, 80, g)
    q[:, 0] = torch.deg2rad(torch.rand(80, generator=g, dtype=q.dtype) * 4 - 2)  # joint 1 within +-2 deg
    m = VirtualRobot(ROBOT, [], seed=5).measure(q, noise_mm=0.02)
    ctx = context_of(ROBOT, m)
    model = CalibrationModel(ROBOT, ["gear_periodic:1"])
    res = fit(model, ctx, m.xyz, pose=m.pose)
    names = model.param_names()
    full, bare = determination(res, names, ctx), determination(res, names, ctx, partners=False)
    assert full and any(d["partner"] for d in full)  # the harmonics of a narrow joint are not determined
    assert [(d["name"], d["why"], d["value"], d["sd"]) for d in bare] == \
        [(d["name"], d["why"], d["value"], d["sd"]) for d in full]
    assert all(d["partner"] == "" and d["r2"] == 0.0 for d in bare)
