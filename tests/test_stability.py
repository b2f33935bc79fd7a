"""Physics or absorption (torchcal.diagnosis.stability), on data of an independent plain-numpy
robot (tests/npsim.py): an encoder-scale error of joint 2 fitted by `encoder_scale:2` is
physics; a joint-2 error quadratic in q2, which the same effect only absorbs (its slope,
fitted below the median of q2, has the other sign above it), is not."""

import math
from pathlib import Path

import numpy as np
import torch
from npsim import numpy_fk

from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.diagnosis.stability import halves, stability
from torchcal.diagnosis.step import fit_options
from torchcal.effects import context_of
from torchcal.io.robot_file import load_robot_file
from torchcal.measurements import Measurements

UR10 = load_robot_file(Path(__file__).resolve().parents[1] / "examples" / "ur10" / "ur10.json")
EFFECTS = ["base_frame", "tool_offset", "encoder_scale:2"]


def _session(dq2, seed, n=200):
    """n random poses (q2 in [-170, -10] deg), MD-H errors, a joint-2 error dq2(q2) rad,
    0.02 mm noise per axis; plain numpy."""
    def dq(q):
        out = np.zeros_like(q)
        out[:, 1] = dq2(q[:, 1])
        return out
    return _measured(dq, seed, n)


def _measured(dq, seed, n):
    """n random poses (q2 in [-170, -10] deg), MD-H errors, joint errors dq(q) (n, 6) rad
    added to the commanded angles, 0.02 mm noise per axis; plain numpy."""
    rng = np.random.default_rng(seed)
    q = np.column_stack([rng.uniform(-np.pi, np.pi, n), np.radians(rng.uniform(-170, -10, n)),
                         rng.uniform(-2.6, 2.6, n), rng.uniform(-np.pi, np.pi, (n, 3))])
    dev = np.zeros((6, 5))
    dev[:, 0] = rng.normal(0, math.radians(0.02), 6)
    dev[:, 1:3] = rng.normal(0, 0.2, (6, 2))
    xyz = numpy_fk(UR10, q + dq(q), dev) + rng.normal(0, 0.02, (n, 3))
    return Measurements(pose=torch.arange(n), q=torch.from_numpy(q), xyz=torch.from_numpy(xyz))


def _stability(m):
    ctx = context_of(UR10, m)
    full = fit(CalibrationModel.for_measurements(UR10, EFFECTS, m), ctx, m.xyz, **fit_options(m))
    return stability(full, "encoder_scale:2", m, ctx, sigma_mm=0.02, sigma_deg=0.01)


def test_an_effect_that_is_the_physics_gains_where_it_was_not_fitted():
    st = _stability(_session(lambda q2: 1e-3 * q2, seed=3))
    assert st.stable and st.splits == 6, st
    assert st.gain_mm > 0


def test_an_effect_that_only_absorbs_loses_its_gain_carried_to_the_other_half():
    c = np.radians(-60.0)
    st = _stability(_session(lambda q2: 2e-4 * (q2 - c) ** 2, seed=4))
    assert not st.stable and st.split == "q2", st
    assert st.p_value >= 0.01 and "median of q2" in st.words()


def test_halves_split_each_joint_at_its_median_by_pose():
    """Two rows per pose stay on one side; each half holds half the poses."""
    q = torch.from_numpy(np.random.default_rng(7).uniform(-1, 1, (10, 3))).repeat_interleave(2, 0)
    m = Measurements(pose=torch.arange(10).repeat_interleave(2), q=q, xyz=torch.zeros(20, 3))
    h = halves(m)
    assert list(h) == ["q1", "q2", "q3"]
    for j, (name, side) in enumerate(h.items()):
        assert (side[::2] == side[1::2]).all() and side.sum() == 10
        assert np.array_equal(side[::2] == 1, q[::2, j].numpy() > np.median(q[::2, j].numpy()))


def test_discover_names_only_the_stable_effects_and_says_why_the_others_are_not():
    from torchcal.diagnosis.diagnose import Discovery
    from torchcal.diagnosis.stability import Stability

    st = {"joint_compliance:2": Stability(1e-9, "q3", 0.004, 6), "joint_clearance:1": Stability(0.4, "q1", -0.001, 6)}
    d = Discovery([], ["base_frame", "joint_compliance:2", "joint_clearance:1"], None, [], stability=st)
    assert d.absorbing == ["joint_clearance:1"]
    first, second = d.final_words().splitlines()
    assert first == "final effects: base_frame, joint_compliance:2"
    assert second.startswith("  joint_clearance:1: in the model as a fit term only, not named: fitted on the poses on "
                             "one side of the median of q1") and "gain -1.0 um, p 0.4 >= 0.01" in second


# -- an effect on several joints is judged joint by joint ---------------------------------
ARCSEC = math.pi / (180 * 3600)


def _two_joint_session(seed, n=300):
    """n random poses as `_session`; joint 2 carries a gear harmonic (order 17, 60 arcsec:
    physics for joint_periodic:2@17); joint 1 carries an order-12 ripple whose amplitude
    follows q2 (a hose-like pull that grows as the arm lowers: zero at q2 = -130 deg, 30
    arcsec per 80 deg of q2 beyond it), which joint_periodic:1@12 can only absorb: its
    amplitude, fitted on the poses of one side of the median of q2, is not the other
    side's. Plain numpy."""
    def dq(q):
        out = np.zeros_like(q)
        out[:, 1] = 60 * ARCSEC * np.sin(17 * q[:, 1] + 0.4)
        out[:, 0] = 30 * ARCSEC * (q[:, 1] - np.radians(-130)) / np.radians(80) * np.sin(12 * q[:, 0] + 1.0)
        return out
    return _measured(dq, seed, n)


def test_a_periodic_effect_on_two_joints_names_the_joint_that_holds_and_labels_the_absorbing_one():
    from torchcal.diagnosis.diagnose import Discovery

    m = _two_joint_session(seed=5)
    ctx = context_of(UR10, m)
    spec = "joint_periodic:1@12,2@17"
    full = fit(CalibrationModel.for_measurements(UR10, ["base_frame", "tool_offset", spec], m), ctx, m.xyz,
               **fit_options(m))
    st = stability(full, spec, m, ctx, sigma_mm=0.02, sigma_deg=0.01)
    assert sorted(st.parts) == [1, 2]
    part1, st1 = st.parts[1]
    part2, st2 = st.parts[2]
    assert (part1, part2) == ("joint_periodic:1@12", "joint_periodic:2@17")
    assert st2.stable and st2.splits > 0 and st2.gain_mm > 0, st2
    assert not st1.stable and st1.split == "q2", st1
    assert not st.stable and (st.p_value, st.split) == (st1.p_value, st1.split)
    d = Discovery([], ["base_frame", "tool_offset", spec], full, [], stability={spec: st})
    assert d.named == ["base_frame", "tool_offset", "joint_periodic:2@17"]
    assert d.absorbing == ["joint_periodic:1@12"]
    first, second = d.final_words().splitlines()
    assert first == "final effects: base_frame, tool_offset, joint_periodic:2@17"
    assert second.startswith("  joint_periodic:1@12: in the model as a fit term only, not named: fitted on the poses "
                             "on one side of the median of q2")
    js = d.to_dict()
    assert js["named"] == d.named and js["absorbing"] == d.absorbing
    assert js["stability"][spec]["parts"]["2"]["stable"] and not js["stability"][spec]["parts"]["1"]["stable"]


def test_part_specs_split_an_effect_by_joint_and_leave_one_joint_effects_whole():
    from torchcal.diagnosis.stability import part_specs

    assert part_specs("joint_periodic:1@12+22,2@20+29,4@5", 6) == {
        1: ("joint_periodic:1@12+22", "joint_periodic:2@20+29,4@5"),
        2: ("joint_periodic:2@20+29", "joint_periodic:1@12+22,4@5"),
        4: ("joint_periodic:4@5", "joint_periodic:1@12+22,2@20+29")}
    assert part_specs("gear_periodic:1,3", 6) == {1: ("gear_periodic:1", "gear_periodic:3"),
                                                   3: ("gear_periodic:3", "gear_periodic:1")}
    assert part_specs("joint_periodic:2@17", 6) == {} and part_specs("base_compliance", 6) == {}


def test_the_named_part_of_an_effect_keeps_the_joints_that_hold_in_spec_order():
    from torchcal.diagnosis.stability import Stability

    ok, bad = Stability(1e-6, "q1", 0.002, 6), Stability(0.5, "q5", -0.003, 6)
    st = Stability(0.5, "q5", -0.003, 6, parts={1: ("joint_periodic:1@12+22", ok), 2: ("joint_periodic:2@20", ok),
                                                 4: ("joint_periodic:4@7", bad)})
    assert st.split_spec("joint_periodic:1@12+22,2@20,4@7") == (["joint_periodic:1@12+22,2@20"],
                                                                 [("joint_periodic:4@7", bad)])
    none = Stability(0.5, "q5", -0.003, 6, parts={1: ("gear_periodic:1", bad), 2: ("gear_periodic:2", bad)})
    assert none.split_spec("gear_periodic:1,2") == ([], [("gear_periodic:1", bad), ("gear_periodic:2", bad)])
    assert Stability(0.5, "q5", -0.003, 6).split_spec("encoder_scale:2")[0] == []
