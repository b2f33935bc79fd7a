"""`torchcal.folds.fold_of_pose`: whole poses to one fold, reproducible from the seed, and
a fold count that cross-validation can use (2 or more)."""

import numpy as np
import pytest
import torch

from torchcal.errors import InputError
from torchcal.folds import fold_of_pose


def test_every_row_of_a_pose_is_in_one_fold_and_the_folds_are_balanced():
    pose = np.repeat(np.arange(23), 3)[np.random.default_rng(4).permutation(69)]  # 23 poses x 3 rows, shuffled
    f = fold_of_pose(torch.from_numpy(pose), seed=1, folds=5)
    for p in range(23):
        assert len(set(f[pose == p].tolist())) == 1
    per_fold = np.bincount([f[pose == p][0] for p in range(23)], minlength=5)
    assert per_fold.max() - per_fold.min() <= 1  # a permutation taken modulo 5: 5, 5, 5, 4, 4 poses
    assert np.array_equal(f, fold_of_pose(pose, seed=1, folds=5))  # numpy or torch, the same seed: the same folds
    assert not np.array_equal(f, fold_of_pose(pose, seed=2, folds=5))


@pytest.mark.parametrize("folds", [1, 0, -3, 2.5, True])
def test_a_fold_count_below_two_is_one_clear_error(folds):
    """One fold leaves nothing to fit on (the fold fits failed with 'Singular matrix')."""
    with pytest.raises(InputError, match=rf"folds: expected an integer of 2 or more .* got {folds!r}$"):
        fold_of_pose(np.arange(10), seed=0, folds=folds)
