"""`tool_offset`: TCP / reflector position on the flange.

Parameters (3): [tool_x, tool_y, tool_z] mm, added to the robot's nominal TCP point in
the flange frame. Largely absorbed by the last link's geometric parameters.
"""

from torchcal.effects.base import Effect


class ToolOffset(Effect):
    name = "tool_offset"

    def param_names(self):
        return ["tool_x", "tool_y", "tool_z"]

    def param_units(self):
        return ["mm", "mm", "mm"]

    def tool_point(self, p, ctx):
        return p
