"""`torchcal.diagnosis.dependence.signed_components`: the signed residual component along a
variable's fitted dependence, which separates what the residual length cannot (backlash)."""

import numpy as np
import torch

import torchcal
from torchcal.diagnosis.dependence import signed_components
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses

R = torchcal.robot("kr1000titan")


def _session(n=120, seed=4):
    q = random_poses(R, n, torch.Generator().manual_seed(seed))
    return Measurements(torch.arange(n), q, R.fk(q))  # q_prev: the previous row's angles


def test_an_angle_error_that_flips_with_the_approach_is_signed_by_it():
    """Residual = a joint-3 angle error of +-0.1 mrad by the approach direction of joint 3
    (backlash): the component along the approach_q3 dependence is, row by row, the hand
    computed signed TCP displacement +-1e-4 |dP/dq3|; the length would be the same for both."""
    m = _session()
    J3 = R.joint_jacobian(m.q)[:, :, 2].numpy()  # (N, 3) mm/rad
    s = np.sign((m.q - m.q_prev)[:, 2].numpy())
    r = 1e-4 * s[:, None] * J3
    comp = signed_components(R, m, r)["approach_q3"]
    np.testing.assert_allclose(comp, 1e-4 * s * np.linalg.norm(J3, axis=1), rtol=1e-6, atol=1e-9)


def test_a_smooth_dependence_is_signed_by_the_direction_of_growth():
    """Residual = a TCP x offset growing linearly with q2 from -0.2 to +0.2 mm: the q2
    component is that offset (sign: larger at the largest q2), the residual length is |offset|."""
    m = _session(seed=5)
    q2 = m.q[:, 1].numpy()
    off = 0.4 * (q2 - q2.min()) / np.ptp(q2) - 0.2
    r = np.stack([off, 0 * off, 0 * off], 1)
    comp = signed_components(R, m, r)["q2"]
    np.testing.assert_allclose(comp, off, atol=1e-8)
