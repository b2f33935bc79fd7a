"""The one way in (torchcal.api): forgiving inputs, one result, to_dict = the CLI's JSON.

Reference: noise-free measurements of a model with known deviations, positions computed
here; a preset name, a Robot and a CalibrationModel give the same fit; a CSV path and
Measurements give the same fit; wrong inputs fail with an InputError naming the argument.
"""

import pytest
import torch
from torch.testing import assert_close

import torchcal
from torchcal.calibration.model import CalibrationModel
from torchcal.effects import make_context
from torchcal.io.measurement_csv import write_measurements
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses
from torchcal.io import modelfile


@pytest.fixture(scope="module")
def data(kr):
    model = CalibrationModel(kr)
    theta = torch.zeros(model.n_params, dtype=torch.float64)
    theta[[1, 7, 12]] = torch.tensor([0.4, -0.3, 0.2], dtype=torch.float64)  # dd1, da2, dd3 mm
    q = random_poses(kr, 40, 5)
    xyz = model.predict(theta, make_context(kr, q))
    return Measurements(torch.arange(40), q, xyz), theta


def test_fit_from_name_robot_model_and_csv(kr, data, tmp_path):
    m, theta = data
    res = torchcal.fit("kr1000titan", m)
    assert res.status == "converged" and res.rms_mm < 1e-6
    p = res.model.predict(res.theta, make_context(kr, m.q))
    assert_close(p, m.xyz, atol=1e-6, rtol=0)  # identifiable combination reproduces the data
    write_measurements(tmp_path / "m.csv", m)
    for first, meas in ((kr, m), (CalibrationModel(kr), m), ("kr1000titan", tmp_path / "m.csv")):
        other = torchcal.fit(first, meas)
        assert_close(other.theta, res.theta, atol=1e-9, rtol=0)
    d = modelfile.to_dict(res)
    assert d["fit"]["status"] == "converged" and d["robot"] == "kr1000titan"


def test_evaluate_compensate_and_errors(kr, data):
    m, _ = data
    res = torchcal.fit(kr, m, effects=["base_frame"])
    ev = torchcal.evaluate(res, m)
    dist = (m.xyz - res.model.predict(res.theta, make_context(kr, m.q))).norm(dim=-1)
    assert ev.n == 40 and ev.to_dict()["rms_mm"] == pytest.approx(float(dist.pow(2).mean().sqrt()))
    assert ev.to_dict()["max_mm"] == pytest.approx(float(dist.max()))
    comp = torchcal.compensate(res, m.xyz[:5])
    assert comp.converged.all()
    assert_close(res.model.predict(res.theta, make_context(kr, comp.q)), m.xyz[:5], atol=1e-6, rtol=0)
    with pytest.raises(torchcal.InputError, match="effects: given with a CalibrationModel or a fitted model"):
        torchcal.fit(res, m, effects=["base_frame"])
    with pytest.raises(torchcal.InputError, match="robot_or_model: expected a preset name"):
        torchcal.fit(42, m)
    with pytest.raises(torchcal.InputError, match="measurements: expected Measurements or a CSV path"):
        torchcal.fit(kr, [1, 2])
    with pytest.raises(torchcal.InputError, match="model: expected a FitResult"):
        torchcal.evaluate(kr, m)


def test_discover_refuses_a_transfer_session_of_another_robot(kr, data, tmp_path):
    """The other session is held to the check the data get: the positions of another arm
    (the UR5e's nominal geometry at KR 1000 poses, metres off) are one InputError naming
    its file before any search, not a transfer figure of metres that vetoes every step."""
    m, _ = data
    ur = CalibrationModel(torchcal.robot("ur5e"))
    q = random_poses(kr, 40, 6)
    xyz = ur.predict(torch.zeros(ur.n_params, dtype=torch.float64), make_context(ur.robot, q))
    write_measurements(tmp_path / "ur5e.csv", Measurements(torch.arange(40), q, xyz))
    with pytest.raises(torchcal.InputError, match=r"ur5e\.csv: cannot come from kr1000titan"):
        torchcal.discover("kr1000titan", m, transfer=tmp_path / "ur5e.csv", max_rounds=0)


def test_discover_refuses_a_transfer_session_without_the_datas_temp_c(data, tmp_path):
    """Data with temp_c make thermal_expansion a candidate, and every candidate is scored on
    the transfer session: one without temp_c was a TypeError traceback mid-search, now
    an InputError naming the transfer file and the column, before any search."""
    m, _ = data
    warm = Measurements(m.pose, m.q, m.xyz, temp_c=torch.full((len(m),), 25.0, dtype=torch.float64))
    write_measurements(tmp_path / "cold.csv", m)
    with pytest.raises(torchcal.InputError, match=r"cold\.csv: the transfer session has no temp_c column"):
        torchcal.discover("kr1000titan", warm, transfer=tmp_path / "cold.csv", max_rounds=1)


def test_calibrate_refuses_a_partition_file_of_another_robot(kr, data, tmp_path):
    """`torchcal.calibrate(robot, data, partition=PATH)` reads the partition for its robot:
    another robot's is one InputError naming the file, the robot's own is used."""
    from torchcal.io.partition_file import save_partition
    from torchcal.partition.zones import partition_workspace
    from torchcal.reliability.sweep import sweep

    m, _ = data
    m = Measurements(m.pose.repeat(2), m.q.repeat(2, 1), m.xyz.repeat(2, 1))  # two (noise-free) repeats a pose
    sw = sweep(kr, random_poses(kr, 40, 9), n_samples=20)
    path = tmp_path / "zones.json"
    save_partition(partition_workspace(sw.positions, sw.r_set, 2, [1, 1], seed=0), path, made_for=sw.robot)
    with pytest.raises(torchcal.InputError, match=rf"^{path}: made for robot 'kr1000titan' .*, not 'ur5e' "):
        torchcal.calibrate("ur5e", m, partition=path)
    res = torchcal.calibrate(kr, m, partition=path)
    assert len(res.zones) == 2


def test_a_model_path_of_any_name_is_read_and_named(tmp_path):
    """compensate / evaluate given a model path that does not end in .json (the data file
    by mistake) name the file and what it is; compensate said 'model: expected a FitResult
    (a fitted model) or a MODEL.json path, got str'."""
    from torchcal.errors import InputError

    data = tmp_path / "data.csv"
    data.write_text("pose,q1,q2,q3,q4,q5,q6,x,y,z\n0,0,0,0,0,0,0,1,2,3\n")
    with pytest.raises(InputError, match=r"data\.csv: not a valid model file: a CSV table"):
        torchcal.compensate(data, torch.zeros(1, 3, dtype=torch.float64) + 500.0)
    with pytest.raises(InputError, match=r"data\.csv: not a valid model file: a CSV table"):
        torchcal.evaluate(data, data)


def test_compensate_checks_the_callers_seeds(kr, data):
    """q0 of torchcal.compensate: one seed per target, radians (degrees given as radians
    refused; before, the solve converged at joint values thousands of degrees off, with a
    calibrated-range warning only), seeds far from their targets named in one warning."""
    import warnings

    from torchcal.calibration.checks.verdict import MismatchWarning

    m, _ = data
    res = torchcal.fit(kr, m)
    t, q = m.xyz[:4], m.q[:4]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        good = torchcal.compensate(res, t, q0=q)
    assert good.converged.all()
    with pytest.raises(torchcal.InputError, match=r"^q0: seed angles reach [0-9.]+ rad, beyond what a joint can turn "
                                                  r"\([0-9.]+ rad\): they look like degrees; seeds are in radians"):
        torchcal.compensate(res, t, q0=torch.rad2deg(q))
    with pytest.raises(torchcal.InputError, match=r"^q0: expected \(4, 6\) rad, one seed per target, got shape \(3, 6\)"):
        torchcal.compensate(res, t, q0=q[:3])
    with pytest.raises(torchcal.InputError, match=r"^q0: expected \(4, 6\) rad, one seed per target, got shape \(6,\)"):
        torchcal.compensate(res, t, q0=q[0])
    far = q.clone()
    far[2] += 0.5
    with pytest.warns(MismatchWarning, match=r"^q0: 1 seed\(s\) lie more than 100 mm from their targets .* row\(s\) 3;"):
        torchcal.compensate(res, t, q0=far)


@pytest.mark.parametrize("call, words", [
    (lambda m, res: torchcal.fit("kr1000titan", m, effects="base_frame tool_offset"),
     r"^effects: expected a list of effect specs, got the string 'base_frame tool_offset'; "
     r"pass effects=\['base_frame', 'tool_offset'\]$"),
    (lambda m, res: torchcal.fit("kr1000titan", m, sigma_mm=-1), r"^sigma_mm: expected a finite number > 0, got -1$"),
    (lambda m, res: torchcal.diagnose("kr1000titan", m, sigma_deg=float("nan")),
     r"^sigma_deg: expected a finite number > 0, got nan$"),
    (lambda m, res: torchcal.compensate(res, torch.zeros(0, 3, dtype=torch.float64)),
     r"^targets: expected \(M, 3\) mm, M >= 1, got shape \(0, 3\)$"),
    (lambda m, res: torchcal.compensate(res, m.xyz[:2], tol_mm=-1e-6), r"^tol_mm: expected a finite number > 0"),
    (lambda m, res: torchcal.compensate(res, m.xyz[:2], max_iter=0), r"^max_iter: expected an integer >= 1, got 0$"),
    (lambda m, res: torchcal.api.simulate("ur5e", n=0), r"^n: expected an integer >= 1, got 0$"),
    (lambda m, res: torchcal.api.simulate("ur5e", n=5, repeats=0), r"^repeats: expected an integer >= 1, got 0$"),
    (lambda m, res: torchcal.api.simulate("ur5e", n=5, noise_mm=-0.02),
     r"^noise_mm: expected a finite number >= 0, got -0.02$")])
def test_argument_values_that_cannot_be_right_are_named(kr, data, call, words):
    """Before: effects as one string read letter by letter ('unknown effect b'); a negative
    sigma fitted in silence, a NaN one ended 'no parameter is identifiable'; no targets, or
    simulate n=0, a torch.cat traceback; a negative tolerance, max_iter 0, repeats 0 or a
    negative noise ran in silence."""
    m, _ = data
    res = torchcal.fit(kr, m)
    with pytest.raises(torchcal.InputError, match=words):
        call(m, res)
