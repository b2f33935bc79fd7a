"""The physical-effects vocabulary (docs/design.md): one module per effect.

`build(spec, robot)` turns an `EffectSpec` (or its text, e.g. 'joint_compliance:2,3')
into an `Effect`. Joints are 1-based everywhere a person sees them.

One registry (`torchcal.effects.registry.REGISTRY`, name -> class) holds the built-in
effects and those a user adds: `register_effect(cls)`, `load_module("my_effects.py")` (the
command line's ``--effects-module``) or an installed package's ``torchcal.effects``
entry point. docs/effects.md shows how to write one.
"""

from torchcal.effects.axis_tilt import AxisTilt
from torchcal.effects.backlash import Backlash
from torchcal.effects.base import Effect
from torchcal.effects.base_compliance import BaseCompliance
from torchcal.effects.base_frame import BaseFrame
from torchcal.effects.context import Context, approach_directions, context_of, make_context
from torchcal.effects.cross_coupling import CrossCoupling
from torchcal.effects.encoder_scale import EncoderScale
from torchcal.effects.gear_periodic import GearPeriodic
from torchcal.effects.gear_transmission import GearTransmission
from torchcal.effects.joint_clearance import JointClearance
from torchcal.effects.joint_compliance import JointCompliance
from torchcal.effects.joint_periodic import JointPeriodic
from torchcal.effects.link_bending import LinkBending
from torchcal.effects.registry import REGISTRY, load_entry_points, load_module, lookup, register_effect, unregister_effect
from torchcal.effects.thermal_expansion import ThermalExpansion
from torchcal.effects.tool_offset import ToolOffset

for _cls in (BaseFrame, ToolOffset, JointCompliance, GearPeriodic, Backlash, EncoderScale,
             ThermalExpansion, JointClearance, CrossCoupling, AxisTilt, BaseCompliance, LinkBending,
             GearTransmission, JointPeriodic):
    register_effect(_cls, "torchcal.effects", builtin=True)


def build(spec, robot) -> Effect:
    """An effect from a spec ('name' or 'name:J,J') or an EffectSpec, for `robot`."""
    from torchcal.effects.spec import parse_spec

    if isinstance(spec, str):
        spec = parse_spec(spec, robot.n)
    if spec.orders:
        return lookup(spec.name)(robot, spec.joints, spec.orders)
    return lookup(spec.name)(robot, spec.joints)


__all__ = ["AxisTilt", "BaseCompliance", "Context", "CrossCoupling", "Effect", "approach_directions", "GearTransmission", "JointPeriodic", "LinkBending", "REGISTRY", "build", "context_of", "load_entry_points", "load_module",
           "lookup", "make_context", "register_effect", "unregister_effect"]
