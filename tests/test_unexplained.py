"""What the model leaves unexplained: repeats of a pose are one piece of
evidence; the noise floor comes from repeats; structure outside the vocabulary is reported
with the variable it depends on; a right model leaves nothing significant.

Data: the project's simulator (KR 1000 Titan, geometric deviations only as the "real"
robot), 0.02 mm noise per axis, plus errors injected here by hand.
"""

import math

import numpy as np
import pytest
import torch

import torchcal
from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.diagnosis.diagnose import ALPHA, diagnose
from torchcal.diagnosis.unexplained import noise_floor_from_neighbours, noise_floor_from_repeats, unexplained
from torchcal.effects import make_context
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot

ROBOT = torchcal.robot("kr1000titan")
NOISE = 0.02


def with_error(m: Measurements, dxyz: torch.Tensor) -> Measurements:
    return Measurements(m.pose, m.q, m.xyz + dxyz, m.payload_kg, m.temp_c, q_prev=m.q_prev)


@pytest.fixture(scope="module")
def repeated_null():
    """60 poses x 4 repeats; a 0.05 mm error per axis shared by each pose's repeats (a
    target-nest / repeatability error), no physical effect."""
    vr = VirtualRobot(ROBOT, [], seed=21)
    m = vr.measure(random_poses(ROBOT, 60, 22), repeats=4, noise_mm=NOISE, seed=23)
    shared = 0.05 * torch.randn(60, 3, generator=torch.Generator().manual_seed(24), dtype=torch.float64)
    m = with_error(m, shared[m.pose])
    return m, diagnose(ROBOT, m)


def test_repeats_with_a_shared_pose_error_give_no_verdict(repeated_null):
    m, d = repeated_null
    assert d.verdict is None, [c.to_dict() for c in d.candidates[:3]]
    level = ALPHA / 2 / len(d.candidates)  # the first family's Bonferroni level
    assert min(c.p_value for c in d.candidates) >= level, [(c.spec, c.p_value) for c in d.candidates[:3]]
    assert not d.unexplained.significant, d.unexplained.strengths


def test_noise_floor_from_repeats_is_the_simulated_noise(repeated_null):
    m, d = repeated_null
    u = d.to_dict()["unexplained"]
    assert set(u) == {"significant", "rms_mm", "noise_floor_mm", "noise_floor_from", "correlates_with",
                      "learnable_rms_mm", "carried_by", "probe", "probe_left_rms_mm"}
    assert u["noise_floor_from"] == "repeats"
    truth = NOISE * math.sqrt(3)  # distance RMS of the per-axis noise
    assert abs(u["noise_floor_mm"] - truth) < 0.15 * truth, (u, truth)
    assert u["rms_mm"] > 1.5 * u["noise_floor_mm"]  # the shared pose error is above the floor


def test_noise_floor_from_repeats_matches_numpy_by_hand():
    g = np.random.default_rng(0)
    pose = np.array([0, 0, 1, 1, 1, 2])
    r = g.normal(size=(6, 3))
    dev = [r[pose == p] - r[pose == p].mean(0) for p in range(3)]
    hand = math.sqrt(sum(float((x ** 2).sum()) for x in dev) / (1 + 2 + 0))
    assert noise_floor_from_repeats(pose, r) == pytest.approx(hand, rel=1e-12)
    assert noise_floor_from_repeats(np.arange(6), r) is None


def geometric_residuals(m):
    model = CalibrationModel(ROBOT, [])
    return fit(model, make_context(ROBOT, m.q, m.payload_kg, m.temp_c), m.xyz).residuals


@pytest.fixture(scope="module")
def bent_link():
    """(m, u): a link that bends with joint 3's angle, a TCP error of 0.2 mm * sin(2 q3)
    along the base z axis, which no effect of the vocabulary models (240 poses); u: what
    the geometric fit leaves unexplained. Read by the two tests below."""
    vr = VirtualRobot(ROBOT, [], seed=31)
    m = vr.measure(random_poses(ROBOT, 240, 32), noise_mm=NOISE, seed=33)
    bend = torch.zeros(len(m), 3, dtype=torch.float64)
    bend[:, 2] = 0.2 * torch.sin(2 * m.q[:, 2])
    m = with_error(m, bend)
    return m, unexplained(ROBOT, m, geometric_residuals(m))


def test_a_bent_link_outside_the_vocabulary_is_significant_and_names_its_joint(bent_link):
    """The bent link: significant, and its joint named."""
    m, u = bent_link
    assert u.significant
    assert [v for v, _ in u.correlates_with] == ["q3"], u.correlates_with  # not its mirror approach_q3
    assert u.rms_mm > 2 * u.noise_floor_mm  # no repeats: the floor is the estimate
    # the floor is the neighbours' estimate, unless one of the two held-out errors (upper
    # bounds) is below it, and the words say which
    best = max(st for st, _ in u.strengths.values())
    by_variable = u.rms_mm * math.sqrt(1 - best)
    bound = min(by_variable, u.probe_left_rms_mm)
    source = "probe" if u.probe_left_rms_mm <= by_variable else "variables"
    q = m.q.numpy()
    near = noise_floor_from_neighbours(np.hstack([np.sin(q), np.cos(q)]), u.residuals)
    if near is not None and near <= bound:
        bound, source = near, "neighbours"
    assert u.noise_floor_mm == pytest.approx(bound, rel=1e-12)
    assert u.floor_from == source and u.to_dict()["noise_floor_from"] == source
    assert {"probe": "upper bound, the probe's held-out error", "neighbours": "estimate from neighbours",
            "variables": "upper bound, the strongest variable's held-out error"}[source] in u.describe()


def test_noise_floor_from_neighbours_recovers_a_known_noise_under_a_smooth_structure():
    """Gamma test on 2000 rows: two angles, a 0.3 mm structure smooth in them (ten times the
    noise), independent noise of known sigma 0.02 mm per axis (0.0346 mm distance RMS): the
    estimate is within 10 % of the truth, where the RMS of the rows is 6 times it; pure
    noise gives the same; too few rows give None."""
    g = np.random.default_rng(11)
    a = g.uniform(-np.pi, np.pi, (2000, 2))
    x = np.hstack([np.sin(a), np.cos(a)])
    s = 0.3 * np.column_stack([np.sin(a[:, 0] + a[:, 1]), np.cos(2 * a[:, 0]), np.sin(a[:, 1])])
    e = 0.02 * g.normal(size=(2000, 3))
    truth = 0.02 * math.sqrt(3)
    assert np.sqrt(((s + e) ** 2).sum(-1).mean()) > 6 * truth
    assert noise_floor_from_neighbours(x, s + e) == pytest.approx(truth, rel=0.1)
    assert noise_floor_from_neighbours(x, e) == pytest.approx(truth, rel=0.1)
    assert noise_floor_from_neighbours(x[:20], e[:20]) is None


def test_the_right_model_leaves_nothing_significant():
    vr = VirtualRobot(ROBOT, [], seed=41)
    m = vr.measure(random_poses(ROBOT, 240, 42), noise_mm=NOISE, seed=43)
    u = unexplained(ROBOT, m, geometric_residuals(m))
    assert not u.significant and u.correlates_with == [], u.strengths
    assert u.noise_floor_mm == pytest.approx(u.rms_mm, rel=0.05)


def test_residual_vs_variables_figure_orders_panels_by_strength_and_marks_the_correlate(tmp_path):
    """Hidden backlash on joint 3, geometric fit: the file is written, the first panel is
    approach_q3 (the variable `unexplained` finds), marked, and panels follow the strengths."""
    import torchcal
    from torchcal.calibration.fit import fit
    from torchcal.calibration.model import CalibrationModel
    from torchcal.cli._viz import _variables_png
    from torchcal.diagnosis.unexplained import unexplained as find, variables
    from torchcal.effects import context_of
    from torchcal.simulation.virtual_robot import VirtualRobot, random_poses
    from viz import figures

    R = torchcal.robot("kr1000titan")
    m = VirtualRobot(R, ["backlash:3"], seed=3).measure(random_poses(R, 120, torch.Generator().manual_seed(7)),
                                                        noise_mm=0.02)
    un = find(R, m, fit(CalibrationModel(R, []), context_of(R, m), m.xyz).residuals)
    assert un.correlates_with[0][0] == "approach_q3"
    _variables_png(tmp_path / "v.png", R, m, un, False, "test")
    assert (tmp_path / "v.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    s = {k: v for k, (v, _) in un.strengths.items()}
    fig = figures.residual_vs_variables_figure(variables(R, m), un.residuals, s, correlates=["approach_q3"])
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible()]
    assert titles[0].startswith("* approach_q3")
    shown = [float(t.split("R2 ")[1]) for t in titles]
    assert shown == sorted(shown, reverse=True) and len(titles) == len(s)
    assert np.allclose(fig.axes[0].lines[0].get_ydata(), np.linalg.norm(un.residuals, axis=1))


def test_ridge_path_matches_numpy_solves():
    from torchcal.diagnosis.unexplained import RIDGE_GRID, _ridge
    g = np.random.default_rng(1)
    X, y = g.normal(size=(40, 7)), g.normal(size=40)
    C = _ridge(torch.from_numpy(X.T @ X), torch.from_numpy(X.T @ y)).numpy()
    for row, mu in zip(C, RIDGE_GRID):
        np.testing.assert_allclose(row, np.linalg.solve(X.T @ X + mu * np.eye(7), X.T @ y), rtol=1e-9, atol=1e-12)


def test_held_out_prediction_never_sees_the_rows_it_predicts():
    """Changing y on one fold leaves that fold's prediction unchanged; an exact linear y
    is predicted exactly (the inner CV picks no shrinkage)."""
    from torchcal.diagnosis.unexplained import held_out_prediction
    g = np.random.default_rng(2)
    X = torch.from_numpy(g.normal(size=(100, 5)))
    fold = np.arange(100) % 5
    y = X @ torch.tensor([1.0, -2.0, 0.5, 0.0, 3.0], dtype=torch.float64)
    torch.testing.assert_close(held_out_prediction(X, y, fold), y, rtol=1e-8, atol=1e-8)
    noisy = y + torch.from_numpy(g.normal(size=100))
    moved = noisy.clone()
    moved[fold == 2] += 10.0
    a, b = held_out_prediction(X, noisy, fold), held_out_prediction(X, moved, fold)
    torch.testing.assert_close(a[fold == 2], b[fold == 2])
    assert (a[fold != 2] - b[fold != 2]).abs().max() > 1e-3  # the other folds do see it


def test_probe_reports_a_smooth_error_as_learnable_from_its_joint(bent_link):
    """0.2 mm * sin(2 q3) along z (the bent link): the probe's held-out RMS falls well
    below the residual's, q3 carries it, and the words say how much is learnable."""
    _, u = bent_link
    d = u.to_dict()
    assert d["significant"] and d["probe"]["p_value"] < 1e-6
    assert d["probe_left_rms_mm"] < 0.6 * d["rms_mm"], d
    # learnable_rms_mm holds the learnable part (not what the probe leaves), and the printed line agrees
    assert d["learnable_rms_mm"] > 0.8 * d["rms_mm"], d
    assert math.isclose(d["learnable_rms_mm"] ** 2 + d["probe_left_rms_mm"] ** 2, d["rms_mm"] ** 2, rel_tol=1e-9)
    assert f"leaves {d['learnable_rms_mm']:.4f} mm learnable" in u.describe()
    assert [c["variable"] for c in d["carried_by"]] == ["q3"], d["carried_by"]
    assert "mm learnable from q3" in u.describe()


def test_discover_json_is_valid_when_the_probe_chooses_no_input(tmp_path):
    """Nothing learnable (geometric-only data): the history JSON is strict JSON (no NaN),
    the probe finds nothing beyond chance; a probe that picks no input is written with
    null length scale and ridge."""
    import json

    from torchcal.cli import main
    from torchcal.diagnosis.probe import Probe
    from torchcal.diagnosis.unexplained import Unexplained

    def strict(text):
        return json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))

    data, hist = tmp_path / "d.csv", tmp_path / "h.json"
    assert main(["simulate", "--robot", "ur5e", "--n", "60", "--noise", "0.02", "--seed", "4",
                 "--out", str(data)]) == 0
    assert main(["discover", str(data), "--robot", "ur5e", "--json", str(hist)]) == 0
    u = strict(hist.read_text())["unexplained"]
    assert u["probe"]["p_value"] >= 0.01 and not u["significant"], u
    none = Unexplained(False, 0.035, 0.035, [], "probe", probe=Probe(0.035, 0.035, 1.0, [], float("nan"), float("nan")),
                       learnable_rms_mm=0.0, probe_left_rms_mm=0.035)
    probe = strict(json.dumps(none.to_dict()))["probe"]
    assert probe["inputs"] == [] and probe["length_scale_rad"] is None and probe["ridge"] is None
