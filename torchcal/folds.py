"""Pose-grouped folds: every row of one pose id goes to the same fold, so a held-out
figure never sees the pose it predicts (repeats of a pose are one piece of evidence).
Used by cross-validation in diagnosis, the probe and the residual stage."""

from __future__ import annotations

import numpy as np

from torchcal.errors import InputError

FOLDS = 5


def fold_of_pose(pose, seed: int, folds: int = FOLDS) -> np.ndarray:
    """(N,) fold 0..folds-1 of each row of pose ids `pose` (N,) (numpy or torch), whole
    poses to one fold: a random permutation of the distinct ids (``default_rng(seed)``)
    taken modulo `folds`."""
    if isinstance(folds, bool) or not isinstance(folds, (int, np.integer)) or folds < 2:
        raise InputError(f"folds: expected an integer of 2 or more (cross-validation holds out one fold of "
                         f"the poses and fits on the others), got {folds!r}")
    pose = pose.cpu().numpy() if hasattr(pose, "cpu") else np.asarray(pose)
    ids, inverse = np.unique(pose, return_inverse=True)
    return (np.random.default_rng(seed).permutation(len(ids)) % folds)[inverse]
