"""torchcal.calibration.plausibility: the determined-by-the-data rule (`undetermined`: a
parameter is set by the prior when its posterior sd is at least half its plausible
scale, the data then carrying less than three times the prior's information; beyond its
plausible size when |value| exceeds the scale; `set_by_prior` applies it to a fit's
parameters) and `collinear_with` (the partner by the closed-form R^2 drop is the one the
per-column regressions name)."""

import math

import numpy as np
import pytest
import torch

import torchcal
from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.plausibility import (DETERMINED_RATIO, collinear_with, determination, set_by_prior,
                                               undetermined)
from torchcal.effects import context_of
from torchcal.simulation.virtual_robot import VirtualRobot, random_poses


def test_half_the_scale_separates_measured_from_set_by_the_prior():
    assert DETERMINED_RATIO == 0.5
    s = math.radians(0.1)
    assert undetermined(0.0, 0.49 * s, s) is None
    assert undetermined(0.0, 0.51 * s, s) == "prior"
    # posterior variance 1 / (data + prior information), prior information 1 / s^2: at the
    # threshold the data carry exactly three times the prior's
    data_info = 1 / (0.5 * s) ** 2 - 1 / s ** 2
    assert data_info == pytest.approx(3 / s ** 2)


def test_beyond_the_plausible_size():
    assert undetermined(1.01, 0.1, 1.0) == "beyond" and undetermined(-1.01, 0.1, 1.0) == "beyond"
    assert undetermined(0.99, 0.1, 1.0) is None
    assert undetermined(5.0, 0.6, 1.0) == "prior"  # set by the prior is said first


class _Model:
    def param_names(self):
        return ["a", "b", "c", "frame"]


def test_set_by_prior_names_the_free_parameters_with_a_wide_posterior():
    scales = torch.tensor([1.0, 1.0, 1.0, math.inf], dtype=torch.float64)
    std = torch.tensor([0.49, 0.5, 0.9, 100.0], dtype=torch.float64)
    free = torch.tensor([True, True, False, True])
    assert set_by_prior(_Model(), std, free, scales) == ["b"]


def _by_regressions(M: np.ndarray, i: int, free: np.ndarray):
    """The definition: R^2 of column i on the other free columns, and the column whose
    removal lowers it most, each by its own least-squares regression."""
    others = [j for j in np.flatnonzero(free) if j != i]
    a = M[:, i] / np.linalg.norm(M[:, i])
    B = M[:, others] / np.linalg.norm(M[:, others], axis=0)

    def r2(cols):
        x = np.linalg.lstsq(B[:, cols], a, rcond=None)[0]
        return 1 - float(((a - B[:, cols] @ x) ** 2).sum())

    idx = list(range(len(others)))
    full = r2(idx)
    drop = [full - r2([k for k in idx if k != j]) for j in idx]
    return others[int(np.argmax(drop))], min(max(full, 0.0), 1.0)


def test_partner_and_r2_are_those_of_the_regressions():
    rng = np.random.default_rng(0)
    for _ in range(10):
        M = rng.normal(size=(300, 40))
        M[:, 5] = 0.9 * M[:, 3] + 0.3 * M[:, 7] + 0.01 * rng.normal(size=300)  # nearly collinear
        M[:, 10] = M[:, 11] + 1e-4 * rng.normal(size=300)
        free = np.ones(40, dtype=bool)
        free[20] = False
        names = [f"p{k}" for k in range(40)]
        for i in (5, 10, 3, 0):
            j, r2 = _by_regressions(M, i, free)
            got = collinear_with(torch.from_numpy(M), i, names, torch.from_numpy(free))
            assert got[0] == names[j] and got[1] == r2


def test_a_rank_near_lstsqs_cut_falls_back_to_the_regressions():
    rng = np.random.default_rng(1)
    M = rng.normal(size=(200, 12))
    M[:, 4] = M[:, 6] - M[:, 8] + 1e-13 * rng.normal(size=200)  # a singular value near the cut
    M[:, 0] = M[:, 6] + 0.05 * rng.normal(size=200)
    free = np.ones(12, dtype=bool)
    B = M[:, 1:] / np.linalg.norm(M[:, 1:], axis=0)
    s = np.linalg.svd(B, compute_uv=False)
    eps = np.finfo(float).eps
    assert eps * 200 * s[1] / 10 < s[-1] < 10 * eps * 200 * s[0]  # the case this test is for
    j, r2 = _by_regressions(M, 0, free)
    got = collinear_with(torch.from_numpy(M), 0, [f"p{k}" for k in range(12)], torch.from_numpy(free))
    assert got == (f"p{j}", r2) and r2 > 0.9


def test_exact_dependencies_among_the_others_give_the_regressions_partner():
    """Position columns of parameters that only orientation rows identify are exactly
    dependent: lstsq cuts them, and a column in such a dependency drops nothing."""
    rng = np.random.default_rng(2)
    for trial in range(10):
        M = rng.normal(size=(300, 30))
        M[:, 12] = M[:, 13] + M[:, 14]  # exact dependencies of the other columns
        M[:, 20] = 0.5 * M[:, 21]
        M[:, 0] = 0.8 * M[:, 3] + 0.4 * M[:, 13] + 0.02 * rng.normal(size=300)
        free = np.ones(30, dtype=bool)
        j, r2 = _by_regressions(M, 0, free)
        got = collinear_with(torch.from_numpy(M), 0, [f"p{k}" for k in range(30)], torch.from_numpy(free))
        assert got == (f"p{j}", r2), (trial, got, j)


# -- determination(..., partners=False) --------------------------------------------------

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


@pytest.mark.parametrize("bound, warned", [(None, False), ("0.005", True)])
def test_a_prior_that_costs_the_fit_is_named_with_its_option(tmp_path, capsys, bound, warned):
    """Hidden MD-H deviations of +-0.5 mm (tests/npsim.py): --max-deviation-mm 0.005 pins
    the lengths near nominal and the rms grows many times; fit says so in one warning line
    naming the option and the rms under the default scales (before: silence), and the
    default bound says nothing."""
    from npsim import physics_session
    from torchcal.cli import main
    from torchcal.io.measurement_csv import write_measurements
    from torchcal.measurements import Measurements

    rob = torchcal.robot("ur5e")
    q = random_poses(rob, 80, 3)
    xyz, _ = physics_session(rob, q.numpy(), seed=5, hidden=[])
    write_measurements(tmp_path / "m.csv", Measurements(torch.arange(80), q, torch.from_numpy(xyz)))
    opt = [] if bound is None else ["--max-deviation-mm", bound]
    assert main(["fit", str(tmp_path / "m.csv"), "--robot", "ur5e", *opt, "--out", str(tmp_path / "f.json")]) == 0
    out, err = capsys.readouterr()
    rms = float(out.split("rms ")[1].split(" mm")[0])
    lines = [ln for ln in err.splitlines() if "prior costs" in ln]
    assert len(lines) == int(warned), err
    if warned:
        assert rms > 0.2  # the cost is real: far above the 0.02 mm noise
        assert "--max-deviation-mm 0.005" in lines[0] and "raise --max-deviation-mm" in lines[0]
        assert "--max-deviation-deg" not in lines[0].split("raise")[1]
        ref = float(lines[0].split("against ")[1].split(" mm")[0])
        assert ref < 0.05  # under the default scales the data reach the noise
    else:
        assert rms < 0.05
