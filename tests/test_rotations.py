"""torchcal.rotations against scipy's Rotation (an independent implementation): the
fixed-axis XYZ convention (scipy's extrinsic 'xyz'), Rodrigues, and the closed-form fits
recovering a known rotation."""

import numpy as np
import pytest
import torch
from torch.testing import assert_close

from torchcal.rotations import (fixed_xyz_to_matrix, kabsch, matrix_to_fixed_xyz, matrix_to_rotvec,
                                procrustes_rotation, rotvec_to_matrix, skew, so3_error)
from torchcal.rotations import _unit_skews

ANGLES = torch.tensor([[0.3, -0.7, 2.1], [0.0, 0.0, 0.0], [-2.5, 1.2, -0.4], [1.0, np.pi / 2 - 1e-3, 0.2]],
                      dtype=torch.float64)


def test_fixed_xyz_is_scipys_extrinsic_xyz_and_round_trips():
    from scipy.spatial.transform import Rotation
    R = fixed_xyz_to_matrix(ANGLES)
    ref = Rotation.from_euler("xyz", ANGLES.numpy()).as_matrix()
    np.testing.assert_allclose(R.numpy(), ref, rtol=0, atol=1e-14)
    assert_close(matrix_to_fixed_xyz(R), ANGLES, rtol=0, atol=1e-9)
    lock = fixed_xyz_to_matrix(torch.tensor([0.0, np.pi / 2, 0.8], dtype=torch.float64))
    assert_close(fixed_xyz_to_matrix(matrix_to_fixed_xyz(lock)), lock, rtol=0, atol=1e-12)


def test_rotvec_both_ways_against_scipy():
    from scipy.spatial.transform import Rotation
    for r in (torch.tensor([0.2, -0.4, 1.1], dtype=torch.float64), torch.tensor([1e-9, 0.0, -2e-9], dtype=torch.float64)):
        np.testing.assert_allclose(rotvec_to_matrix(r).numpy(), Rotation.from_rotvec(r.numpy()).as_matrix(),
                                   rtol=0, atol=1e-15)
        assert_close(matrix_to_rotvec(rotvec_to_matrix(r)), r, rtol=0, atol=1e-12)
    g = torch.func.jacfwd(rotvec_to_matrix)(torch.zeros(3, dtype=torch.float64))
    assert torch.isfinite(g).all() and float(g[2, 1, 0]) == pytest.approx(1.0)  # d R / d r = [e_k]x at 0


def test_fits_recover_a_known_rotation():
    gen = torch.Generator().manual_seed(0)
    R = fixed_xyz_to_matrix(ANGLES[0])
    P = torch.randn(20, 3, generator=gen, dtype=torch.float64) * 100
    Rk, t = kabsch(P, P @ R.T + torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    assert_close(Rk, R, rtol=0, atol=1e-12)
    assert_close(t, torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64), rtol=0, atol=1e-10)
    A = fixed_xyz_to_matrix(torch.rand(10, 3, generator=gen, dtype=torch.float64) * 3)
    X = fixed_xyz_to_matrix(ANGLES[2])
    assert_close(procrustes_rotation(A, A @ X), X, rtol=0, atol=1e-12)
    assert float(torch.linalg.det(procrustes_rotation(A, -A))) == pytest.approx(1.0)  # proper, never a reflection
    small = torch.tensor([1e-4, -2e-4, 3e-4], dtype=torch.float64)
    assert_close(so3_error(X, X @ rotvec_to_matrix(small)), small, rtol=1e-6, atol=0)


def test_skew_is_the_cross_product():
    g = torch.Generator().manual_seed(3)
    w, x = torch.randn(4, 2, 3, generator=g, dtype=torch.float64), torch.randn(4, 2, 3, generator=g,
                                                                                dtype=torch.float64)
    S = skew(w)  # (4, 2, 3, 3)
    assert S.shape == (4, 2, 3, 3)
    assert torch.allclose((S @ x[..., None])[..., 0], torch.linalg.cross(w, x), atol=1e-14)
    assert torch.equal(S, -S.transpose(-1, -2))
    assert torch.allclose(skew(w[0, 0]) @ x[0, 0], torch.linalg.cross(w[0, 0], x[0, 0]), atol=1e-14)  # one vector


# -- _unit_skews -------------------------------------------------------------------------

def test_unit_skews_are_the_cross_products_of_the_axes():
    E = _unit_skews(torch.float64, torch.device("cpu"))
    x = torch.tensor([0.3, -1.2, 2.5], dtype=torch.float64)
    eye = torch.eye(3, dtype=torch.float64)
    for k in range(3):
        torch.testing.assert_close(E[k] @ x, torch.linalg.cross(eye[k], x), rtol=0, atol=0)
    assert _unit_skews(torch.float32, torch.device("cpu")).dtype == torch.float32
