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
    rng = np.random.default_rng(seed)
    q = np.column_stack([rng.uniform(-np.pi, np.pi, n), np.radians(rng.uniform(-170, -10, n)),
                         rng.uniform(-2.6, 2.6, n), rng.uniform(-np.pi, np.pi, (n, 3))])
    dev = np.zeros((6, 5))
    dev[:, 0] = rng.normal(0, math.radians(0.02), 6)
    dev[:, 1:3] = rng.normal(0, 0.2, (6, 2))
    qa = q.copy()
    qa[:, 1] += dq2(q[:, 1])
    xyz = numpy_fk(UR10, qa, dev) + rng.normal(0, 0.02, (n, 3))
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
