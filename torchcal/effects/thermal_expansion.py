"""`thermal_expansion`: link lengths scale with temperature.

Parameters (1): ``thermal_coeff`` 1/K. Every MD-H length (a, d) and the tool scale by
``1 + thermal_coeff * (temp_c - REFERENCE_C)``; since the TCP position is homogeneous of
degree one in the lengths, that scales the base-frame TCP position about the base origin.
Needs the ``temp_c`` column. Steel: about 1.2e-5 1/K. A constant temperature is
absorbed by the geometric lengths; only its variation over the session is identifiable.
"""

from torchcal.effects.base import Effect
from torchcal.errors import InputError

REFERENCE_C = 20.0


class ThermalExpansion(Effect):
    name = "thermal_expansion"

    def param_names(self):
        return ["thermal_coeff"]

    def param_units(self):
        return ["1/K"]

    def check_context(self, ctx):
        if ctx.temp_c is None:
            raise InputError("thermal_expansion needs the temp_c column in the measurement file")

    def chain_scale(self, p, ctx):
        return 1.0 + p[0] * (ctx.temp_c - REFERENCE_C)
