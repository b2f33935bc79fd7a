"""Row order (`check_row_order`): backlash reads each row's approach direction from the
row order; a file without prev_q columns and with one row per pose id whose ids step down
at more than 5 % of its rows (sorted or shuffled after the session) gets one warning.
"""

from __future__ import annotations

import warnings

import torch

from torchcal.calibration.checks.verdict import MismatchWarning

ORDER_SHARE = 0.05  # pose ids stepping down at more than this share of rows: not the order taken


class RowOrderWarning(MismatchWarning):
    """A direction-dependent effect on rows that do not look like the measurement order."""


def check_row_order(m, specs) -> int:
    """Warn (`RowOrderWarning`, one line) when an effect that reads the approach direction
    from the row order (backlash) meets a file without ``prev_q`` columns whose pose ids
    step down (id below the previous row's) at more than ORDER_SHARE = 5 % of its rows: rows
    sorted or shuffled after the session (a spreadsheet), whose own order gives every row
    a wrong predecessor. Only files of one row per pose id are judged: a session numbered
    in the order taken steps down nowhere, two sessions joined once; with repeats the
    cycles through the poses run in random order by design (a tracker's, `simulate`'s).
    Returns the number of step-downs (0 when not checked)."""
    from torchcal.measurements import previous_angles

    names = {str(s).split(":")[0] for s in specs}
    if "backlash" not in names or len(m) < 2:
        return 0
    if m.q_prev is not None and not torch.equal(m.q_prev, previous_angles(m.q)):  # true predecessors given
        return 0
    pose = m.pose.detach().cpu()
    if pose.unique().numel() < pose.numel():  # repeats: cycles through the poses in random order (the
        return 0  # tracker's and `simulate`'s), ids out of order by design
    down = (pose[1:] < pose[:-1]).nonzero().flatten()
    if down.numel() <= ORDER_SHARE * len(m):
        return 0
    r = int(down[0]) + 1  # 0-based row that steps down
    warnings.warn(f"{m.source or 'measurements'}: backlash reads each row's approach direction from the row "
                  f"order, but the pose ids step down at {down.numel()} of {len(m)} rows (first: data row {r + 1}, "
                  f"pose id {int(pose[r])} after {int(pose[r - 1])}): rows sorted or shuffled after the session? "
                  f"keep the order taken (a subset: write it with torchcal split, prev_q columns)",
                  RowOrderWarning, stacklevel=3)
    return int(down.numel())
