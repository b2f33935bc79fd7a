"""`thermal_expansion`: link lengths grow with temperature (`temp_c`).

Each non-zero nominal MD-H length L (a_i or d_i) becomes ``L (1 + c_L (temp_c - 20))``:
one coefficient per length (1/K), because the links of a robot are of different
materials and warm differently (castings, carbon arms, the base column...). Steel is
about 1.2e-5 1/K. A uniform expansion is the special case of equal coefficients.

Parameters: ``thermal_a1``, ``thermal_d1``, ... for the non-zero lengths, 1/K.
Needs the ``temp_c`` column. The part at the session's mean temperature is absorbed by
the geometric lengths; only the temperature's variation makes the coefficients
identifiable.
"""


from torchcal.effects.base import Effect
from torchcal.errors import InputError

REFERENCE_C = 20.0
#: plausible expansion coefficient (1/K): steel 1.2e-5, aluminium 2.3e-5; a warm
#: casting or a carbon arm stays well within 1e-4
MAX_COEFFICIENT = 1e-4


class ThermalExpansion(Effect):
    name = "thermal_expansion"
    uses_temperature = True

    def __init__(self, robot, joints=()):
        super().__init__(robot, joints)
        t = robot.table
        # (joint index, table column) of every non-zero length: column 1 = d, 2 = a
        self.lengths = [(i, c) for i in range(robot.n) for c in (2, 1) if abs(float(t[i, c])) > 0]

    def param_names(self):
        return [f"thermal_{'a' if c == 2 else 'd'}{i + 1}" for i, c in self.lengths]

    def param_units(self):
        return ["1/K"] * len(self.lengths)

    def plausible_max(self):
        return [MAX_COEFFICIENT] * len(self.lengths)

    def check_context(self, ctx):
        if ctx.temp_c is None:
            raise InputError("thermal_expansion needs the temp_c column in the measurement file")

    def geometric_offset(self, p, ctx):
        """(N, n, 5) length deviations dd, da = c_L L (temp_c - 20) in mm."""
        n = self.robot.n
        place = p.new_zeros(len(self.lengths), n * 5)
        for k, (i, c) in enumerate(self.lengths):
            place[k, 5 * i + c] = float(self.robot.table[i, c])
        dT = (ctx.temp_c - REFERENCE_C).unsqueeze(-1)  # (N, 1)
        return ((dT * p) @ place).reshape(-1, n, 5)

    def geometric_offset_jacobian(self, p, ctx):
        """(N, n, 5, k): d dd_i or da_i / d c_L = L (temp_c - 20)."""
        out = p.new_zeros(ctx.temp_c.shape[0], self.robot.n, 5, len(self.lengths))
        dT = (ctx.temp_c - REFERENCE_C).to(p)
        for k, (i, c) in enumerate(self.lengths):
            out[:, i, c, k] = dT * float(self.robot.table[i, c])
        return out
