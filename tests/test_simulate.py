"""`torchcal simulate` (torchcal.simulation.session): the noise option's unit check."""

import warnings

import pytest

from torchcal.api import simulate
from torchcal.simulation.session import NoiseUnitWarning


@pytest.mark.parametrize("noise, warned", [(0.00002, True), (0.0009, True), (0.0, False), (0.001, False),
                                           (0.02, False), (0.05, False)])
def test_noise_in_metres_warns(noise, warned):
    """`simulate --noise 0.00002` (metres for 0.02 mm) simulated a 20-nanometre instrument in
    silence. Now noise above 0 and below 1 micrometre (no laser tracker is that quiet) warns
    once naming the value in mm; 0 (noise-free) and the README's 0.02 are silent."""
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        simulate("ur5e", n=3, noise_mm=noise, seed=0)
    mine = [x for x in w if issubclass(x.category, NoiseUnitWarning)]
    if warned:
        assert len(mine) == 1 and f"noise {noise:g} mm is below 0.001 mm" in str(mine[0].message)
        assert f"in metres? ({1000 * noise:g} mm)" in str(mine[0].message)
    else:
        assert mine == []


def test_cli_noise_in_metres_is_one_line(tmp_path, capsys):
    from torchcal.cli import main

    assert main(["simulate", "--robot", "ur5e", "--n", "3", "--noise", "0.00002", "--out", str(tmp_path / "d.csv")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("torchcal: warning: noise 2e-05 mm is below 0.001 mm"), err
