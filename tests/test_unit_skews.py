"""`torchcal.rotations._unit_skews`: the cross-product matrices of the unit vectors."""

import torch

from torchcal.rotations import _unit_skews


def test_unit_skews_are_the_cross_products_of_the_axes():
    E = _unit_skews(torch.float64, torch.device("cpu"))
    x = torch.tensor([0.3, -1.2, 2.5], dtype=torch.float64)
    eye = torch.eye(3, dtype=torch.float64)
    for k in range(3):
        torch.testing.assert_close(E[k] @ x, torch.linalg.cross(eye[k], x), rtol=0, atol=0)
    assert _unit_skews(torch.float32, torch.device("cpu")).dtype == torch.float32
