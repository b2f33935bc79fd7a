"""`register` (`torchcal.calibration.new_setup.register_model`) names the registration rows
where the model extrapolates, as evaluate names them: a temperature outside the range its
thermal effect was fitted on, joint values outside its calibrated range. There the frame is
fitted to the model's extrapolation. Hidden physics: tests/npsim.py (plain-numpy link growth
with temperature, a tracker frame)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

import torchcal
from torchcal.calibration.joint_range import CalibratedRangeWarning, ConditionRangeWarning
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses

from npsim import _rotvec, thermal_session

TURN, SHIFT = _rotvec(np.radians([1.0, -2.0, 20.0])), np.array([1500.0, -300.0, 200.0])  # a new tracker place


def session(rob, q, lo, hi, seed, moved=False):
    temp = np.random.default_rng(seed + 100).uniform(lo, hi, len(q))
    xyz = thermal_session(rob, q.numpy(), temp, seed=7)  # one robot (seed 7), sessions differ in poses
    if moved:
        xyz = xyz @ TURN.T + SHIFT
    return Measurements(torch.arange(len(q)), q, torch.from_numpy(xyz), temp_c=torch.from_numpy(temp))


def caught(fn):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        out = fn()
    return out, {c: [str(x.message) for x in w if issubclass(x.category, c)]
                 for c in (ConditionRangeWarning, CalibratedRangeWarning)}


@pytest.mark.parametrize("robot,seed", [("ur5e", 1), ("puma560", 2), ("kr1000titan", 3)])
def test_register_names_rows_where_the_model_extrapolates_and_only_those(robot, seed):
    rob = torchcal.robot(robot)
    q = random_poses(rob, 160, seed)
    inner = (q[:, 0].abs() <= q[:, 0].abs().quantile(0.75))  # joint 1 within its inner three quarters
    train, rest = q[inner][:80], q[~inner]
    fitted = torchcal.fit(rob, session(rob, train, 18.0, 26.0, seed), ["base_frame", "thermal_expansion"])
    lo, hi = fitted.conditions["temp_c"]
    # honest: poses inside the calibrated range, temperatures inside the fitted ones, a moved tracker
    q_in = random_poses(rob, 400, seed + 10)
    r = fitted.q_range
    q_in = q_in[((q_in >= r[0]) & (q_in <= r[1])).all(1)][:30]
    res, said = caught(lambda: torchcal.register(fitted, session(rob, q_in, 19.0, 25.0, seed + 1, moved=True)))
    assert said == {ConditionRangeWarning: [], CalibratedRangeWarning: []}
    assert res.registration["rms_after_mm"] < 0.2
    # warmer than the fit saw: named with the figures
    _, said = caught(lambda: torchcal.register(fitted, session(rob, q_in, 34.0, 40.0, seed + 2, moved=True)))
    assert len(said[ConditionRangeWarning]) == 1 and said[CalibratedRangeWarning] == []
    assert f"temperature of 30 of 30 registration rows outside the fitted {lo:.4g} .. {hi:.4g} degC" \
        in said[ConditionRangeWarning][0]
    # joint 1 beyond the calibrated range: named
    _, said = caught(lambda: torchcal.register(fitted, session(rob, rest[:30], 19.0, 25.0, seed + 3, moved=True)))
    assert said[ConditionRangeWarning] == [] and len(said[CalibratedRangeWarning]) == 1
    assert "registration rows lie outside the calibrated joint range (joint 1:" in said[CalibratedRangeWarning][0]


@pytest.mark.parametrize("robot,seed", [("ur5e", 4), ("kr1000titan", 5)])
def test_register_names_another_reflector_rather_than_a_model_that_does_not_carry_over(robot, seed):
    """Rows of a reflector 4 mm from the model's (plain-numpy tracker sessions, a tracker
    moved): not 'the model does not carry over' but another reflector, the offset named;
    with the tool re-estimated, neither. A model that extrapolates badly (a 0.3 deg sag
    beyond the joint-2 range it was fitted on) keeps the TransferWarning."""
    from npsim import tracker_session
    from torchcal.calibration.checks.model_data import ReflectorWarning
    from torchcal.calibration.registration import TransferWarning

    rob = torchcal.robot(robot)

    def rows(q, s, reflector=(0.0, 0.0, 290.0), sag=0.05, moved=False):  # s: the robot and its first tracker place
        xyz = tracker_session(rob, q.numpy(), seed=s, reflector_mm=reflector, sag_deg=sag)
        return Measurements(torch.arange(len(q)), q, torch.from_numpy(xyz @ TURN.T + SHIFT if moved else xyz))

    def said(fn):
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            fn()
        return {c: [str(x.message) for x in w if issubclass(x.category, c)]
                for c in (ReflectorWarning, TransferWarning)}

    fitted = torchcal.fit(rob, rows(random_poses(rob, 60, seed), seed), ["base_frame", "tool_offset"])
    new = rows(random_poses(rob, 40, seed + 1), seed, reflector=(0.0, 4.0, 290.0), moved=True)
    got = said(lambda: torchcal.register(fitted, new))
    carry = [x for x in got[TransferWarning] if "does not carry over" in x]
    assert len(got[ReflectorWarning]) == 1 and carry == [], got
    assert "measured at another reflector or nest" in got[ReflectorWarning][0]
    got = said(lambda: torchcal.register(fitted, new, tool=True))
    assert got[ReflectorWarning] == [] and all("carry over" not in x for x in got[TransferWarning])
    q = random_poses(rob, 400, 0)
    near = (q[:, 1] - q[:, 1].median()).abs() < 0.3
    bent = torchcal.fit(rob, rows(q[near][:60], 0, sag=0.3), ["base_frame", "tool_offset"])
    got = said(lambda: torchcal.register(bent, rows(q[~near][:40], 0, sag=0.3)))
    assert got[ReflectorWarning] == [] and any("does not carry over" in x for x in got[TransferWarning]), got
