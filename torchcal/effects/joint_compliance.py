"""`joint_compliance:J`: joint deflection proportional to the gravity torque.

The gravity torque on joint J from a mass m_k with center c_k (fixed in link frame k) is

    tau_J = sum_{k >= J} [ (R_k^T (g x z_J)) . (m_k c_k) + ((o_k - o_J) x g) . z_J m_k ]
            + ((p_tcp - o_J) x g) . z_J m_payload,

with g the unit gravity vector and (z_J, o_J) the axis of joint J, all at the commanded
pose. The deflection is tau_J / K_J. Fitting must not need the true masses, so the
parameters are the products (compliance x gravity x first moments), which enter
linearly; the payload mass is known per row (`payload_kg`), so its coefficient is the
compliance itself. Parameters per joint J, for each link k = J..n:

    compl_J_k_mx, compl_J_k_my, compl_J_k_mz   rad      (G m_k c_k / K_J; unit-vector columns)
    compl_J_k_m                                rad/mm   (G m_k / K_J, lever in mm)
    compl_J_payload                            rad/(kg mm)  (G / K_J)

with G = 9.80665e-3 N m per kg mm. Files and printed tables give the angles in degrees
and the payload term as the joint's compliance 1/K_J in deg/(N m)
(`torchcal.io.modelfile.file_unit`); `torchcal fit` also prints the stiffness K_J in
N m/rad that the payload term gives (`stiffness_nm_per_rad`). The effect is defined on
revolute joints only (a slide's deflection would be a length under a force).

Many of these columns are collinear for a given robot (e.g. a link's moment along its own
axis): the identification keeps the identifiable combinations and holds the rest.
"""

import math

import torch

from torchcal.effects.base import Effect, revolute_only, scatter_joints

G_NM_PER_KG_MM = 9.80665e-3  # N m of torque per (kg x mm of lever)
#: plausible gravity deflection of a joint (deg): a loaded industrial arm deflects by
#: hundredths to tenths of a degree
MAX_DEFLECTION_DEG = 0.5


def gravity_regressor(ctx, joint: int) -> torch.Tensor:
    """Columns of the gravity torque on `joint` (1-based): (N, 4 (n - J + 1) + 1).

    Units: mm for the link columns, kg mm for the payload column.
    """
    f = ctx.frames  # (N, n + 2, 4, 4)
    n = f.shape[1] - 2
    g = ctx.gravity
    z = f[:, joint - 1, :3, 2]  # (N, 3) axis of joint J
    o = f[:, joint - 1, :3, 3]
    gz = torch.linalg.cross(g.expand_as(z), z)  # (N, 3)
    cols = []
    for k in range(joint, n + 1):
        R, ok = f[:, k, :3, :3], f[:, k, :3, 3]
        cols.append(torch.einsum("nij,ni->nj", R, gz))  # R_k^T (g x z): (N, 3)
        cols.append((torch.linalg.cross(ok - o, g.expand_as(z)) * z).sum(-1, keepdim=True))
    tcp = f[:, -1, :3, 3]
    lever = (torch.linalg.cross(tcp - o, g.expand_as(z)) * z).sum(-1, keepdim=True)
    cols.append(lever * ctx.payload_kg.unsqueeze(-1))
    return torch.cat(cols, dim=-1)


class JointCompliance(Effect):
    name = "joint_compliance"
    uses_payload = True
    takes_joints = True

    def __init__(self, robot, joints=()):
        super().__init__(robot, joints)
        revolute_only(self)
        self._cache = None  # (ctx id, regressors): the regressors depend on the data only

    def _n_links(self, j):
        return self.robot.n - j + 1

    def param_names(self):
        names = []
        for j in self.joints:
            for k in range(j, self.robot.n + 1):
                names += [f"compl_{j}_{k}_mx", f"compl_{j}_{k}_my", f"compl_{j}_{k}_mz", f"compl_{j}_{k}_m"]
            names.append(f"compl_{j}_payload")
        return names

    def param_units(self):
        units = []
        for j in self.joints:
            units += ["rad", "rad", "rad", "rad/mm"] * self._n_links(j) + ["rad/(kg mm)"]
        return units

    def plausible_max(self):
        """Each parameter's size that alone deflects the joint by `MAX_DEFLECTION_DEG` at
        the largest value its regressor column can take: 1 for the link-moment columns
        (unit vectors), the robot's reach (mm) for the mass columns, reach x rated payload
        (kg mm) for the payload column."""
        t = self.robot.table.detach().cpu()
        reach = float(t[:, 1].abs().sum() + t[:, 2].abs().sum() + self.robot.tool[:3, 3].detach().cpu().norm())
        d = math.radians(MAX_DEFLECTION_DEG)
        out = []
        for j in self.joints:
            out += [d, d, d, d / reach] * self._n_links(j)
            out.append(d / (reach * max(self.robot.payload_kg, 1.0)))
        return out

    def stiffness_nm_per_rad(self, p) -> dict:
        """{joint J: stiffness K_J N m/rad} from the payload terms of p (k,) (G / K_J
        rad/(kg mm)); only joints whose payload term is positive (the data must vary the
        payload for it to be identified)."""
        out, start = {}, 0
        for j in self.joints:
            start += 4 * self._n_links(j) + 1
            c = float(p[start - 1])
            if c > 0:
                out[j] = G_NM_PER_KG_MM / c
        return out

    def regressors(self, ctx):
        if self._cache is None or self._cache[0] is not ctx:
            self._cache = (ctx, [gravity_regressor(ctx, j) for j in self.joints])
        return self._cache[1]

    def joint_offset(self, p, ctx):
        cols, start = [], 0
        for phi in self.regressors(ctx):
            k = phi.shape[1]
            cols.append(phi @ p[start:start + k])
            start += k
        return scatter_joints(torch.stack(cols, dim=-1), self.joints, ctx.q.shape[1])

    def joint_offset_jacobian(self, p, ctx):
        out = p.new_zeros(ctx.q.shape[0], ctx.q.shape[1], p.shape[0])
        start = 0
        for j, phi in zip(self.joints, self.regressors(ctx)):
            out[:, j - 1, start:start + phi.shape[1]] = phi
            start += phi.shape[1]
        return out

    @staticmethod
    def params_from_physics(robot, joints, masses_kg, coms_mm, stiffness_nm_per_rad) -> torch.Tensor:
        """True parameters for simulation: masses (n,) kg, centers (n, 3) mm in link
        frames, joint stiffness (n,) N m/rad -> p (sum over joints of 4 (n-J+1) + 1,)."""
        masses = torch.as_tensor(masses_kg, dtype=torch.float64)
        coms = torch.as_tensor(coms_mm, dtype=torch.float64)
        stiff = torch.as_tensor(stiffness_nm_per_rad, dtype=torch.float64)
        out = []
        for j in joints:
            c = G_NM_PER_KG_MM / stiff[j - 1]
            for k in range(j, robot.n + 1):
                out += [c * masses[k - 1] * coms[k - 1], (c * masses[k - 1]).reshape(1)]
            out.append(c.reshape(1))
        return torch.cat(out)
