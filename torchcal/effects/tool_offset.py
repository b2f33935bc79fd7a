"""`tool_offset`: TCP / reflector position on the flange, one per measured point.

Parameters: [tool_x, tool_y, tool_z] mm, added to the robot's nominal TCP point in the
flange frame. Largely absorbed by the last link's geometric parameters.

With several measured points per pose (the measurement file's ``point`` column, e.g.
three reflectors on the tool), the effect holds one offset per point id:
``tool_x@ID, tool_y@ID, tool_z@ID`` for each id in ascending order, and each row uses
the offset of its point. A pose with three points fixes the tool's orientation too.
"""

import torch

from torchcal.effects.base import Effect
from torchcal.errors import InputError


class ToolOffset(Effect):
    name = "tool_offset"
    points: tuple = ()  # point ids (ascending) when there are several, else ()

    def set_points(self, points) -> None:
        """Use one offset per point id (points: iterable of ints; one id = a single offset)."""
        ids = sorted({int(p) for p in points})
        self.points = tuple(ids) if len(ids) > 1 else ()

    def param_names(self):
        if not self.points:
            return ["tool_x", "tool_y", "tool_z"]
        return [f"tool_{c}@{p}" for p in self.points for c in "xyz"]

    def param_units(self):
        return ["mm"] * (3 * max(len(self.points), 1))

    def plausible_max(self):
        """No prior: the tool is whatever the user mounted."""
        return None

    def check_context(self, ctx):
        """InputError for data whose point ids this effect has no offset for: with one offset
        per point, an id not among them; with a single offset (a model fitted on one point),
        data of several ids (several reflectors would share it: each off by its distance)."""
        if not self.points:
            ids = [] if ctx.point is None else sorted(set(ctx.point.tolist()))
            if len(ids) > 1:
                shown = ", ".join(map(str, ids[:6])) + (" ..." if len(ids) > 6 else "")
                raise InputError(f"the data have {len(ids)} point ids ({shown}), but the model has one tool offset "
                                 "(fitted on one point): each reflector needs its own; fit a model on data of "
                                 "these points")
            return
        if ctx.point is None:
            raise InputError(f"the model has one tool offset per measured point ({len(self.points)} "
                             "points) but the data have no point column")
        known = torch.tensor(self.points, device=ctx.point.device)
        bad = ~torch.isin(ctx.point, known)
        if bad.any():
            raise InputError(f"point id {int(ctx.point[bad][0])} is not one of the model's points "
                             f"{list(self.points)}")

    def tool_point(self, p, ctx):
        if not self.points:
            return p
        known = torch.tensor(self.points, device=p.device)
        idx = torch.searchsorted(known, ctx.point.to(p.device))
        return p.view(len(self.points), 3)[idx]  # (N, 3)

    def tool_point_jacobian(self, p, ctx):
        """(3, 3) identity, or (N, 3, 3 m) with one offset per point: row r picks its point's."""
        eye = torch.eye(3, dtype=p.dtype, device=p.device)
        if not self.points:
            return eye
        known = torch.tensor(self.points, device=p.device)
        idx = torch.searchsorted(known, ctx.point.to(p.device))  # (N,)
        onehot = torch.nn.functional.one_hot(idx, len(self.points)).to(p)  # (N, m)
        return (onehot[:, None, :, None] * eye[None, :, None, :]).reshape(-1, 3, 3 * len(self.points))
