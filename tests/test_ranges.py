"""Rows beyond what a model was fitted on (torchcal.calibration.checks.ranges): no payload
given to a model fitted on loads (`payload_conditions`) is named once, by compensate and by
evaluate."""

from __future__ import annotations

import pytest
import torch

import torchcal
from torchcal.robots.poses import random_poses


@pytest.mark.parametrize("robot,seed", [("ur5e", 5), ("kr1000titan", 6)])
def test_targets_without_a_payload_for_a_model_fitted_on_loads_are_named(robot, seed):
    """A joint-compliance model fitted on loads of 0..rated kg (plain-numpy gravity sag,
    tests/npsim.py): targets without payload_kg are compensated for an unloaded arm (and
    rows without it evaluated so), one warning line says so with the fitted range; with the
    payload given, and for a model fitted on data without a payload column, nothing is said."""
    import warnings

    from npsim import physics_session
    from torchcal.api import compensate_targets
    from torchcal.calibration.checks.ranges import PayloadAssumedWarning
    from torchcal.calibration.compensate import predict_rows
    from torchcal.measurements import Measurements

    rob = torchcal.robot(robot)
    q = random_poses(rob, 80, seed)
    xyz, load = physics_session(rob, q.numpy(), seed=seed, hidden=["joint_compliance:2,3"], effect_mm=0.5)
    m = Measurements(torch.arange(80), q, torch.from_numpy(xyz), payload_kg=torch.from_numpy(load))
    loaded = torchcal.fit(rob, m, effects=["joint_compliance:2,3"])
    unloaded = torchcal.fit(rob, Measurements(m.pose, m.q, m.xyz), effects=["joint_compliance:2,3"])
    targets = rob.fk(random_poses(rob, 10, seed + 1))
    seeds = torch.rad2deg(random_poses(rob, 10, seed + 1))
    rated = torch.full((10,), float(rob.payload_kg), dtype=torch.float64)

    def run(model, **kw):
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            res = compensate_targets(model, targets, seeds=seeds, **kw)
        return res, [str(x.message) for x in w if issubclass(x.category, PayloadAssumedWarning)]

    bare, said = run(loaded)
    lo, hi = loaded.conditions["payload_kg"]
    assert len(said) == 1 and f"fitted on payloads {lo:.4g} .. {hi:.4g} kg" in said[0], said
    assert "joint_compliance:2,3" in said[0] and "no payload_kg column" in said[0]
    full, said = run(loaded, payload_kg=rated)
    assert said == []
    _, said = run(unloaded)
    assert said == [] and unloaded.conditions["payload_kg"] == [0.0, 0.0]
    # evaluate: the same rows without their payload column are evaluated unloaded, and said so
    for data, model, expected in ((Measurements(m.pose, m.q, m.xyz), loaded, 1), (m, loaded, 0),
                                  (Measurements(m.pose, m.q, m.xyz), unloaded, 0)):
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            torchcal.evaluate(model, data)
        said = [str(x.message) for x in w if issubclass(x.category, PayloadAssumedWarning)]
        assert len(said) == expected and all("evaluated at 0 kg" in x for x in said), said
    # what the warning is about: the unloaded commands miss under the rated load, the loaded ones do not
    def at(c):
        return predict_rows(loaded.model, loaded.theta.expand(10, -1), c.compensation.q, payload_kg=rated)

    miss = float((at(bare) - targets).norm(dim=-1).max())
    assert miss > 10 * float((at(full) - targets).norm(dim=-1).max()) and miss > 0.05
