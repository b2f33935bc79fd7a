"""Independent plain-numpy reference simulator for tests: the MD-H chain written out
(A_i = Rz Tz Tx Rx Ry, a prismatic joint's q adds to d), a tracker frame, a reflector on
the flange, and the physics of hidden effects (gravity deflection from link masses, lost
motion, gear harmonics, a moved base), none of it through torchcal's kernels or effects."""

from __future__ import annotations

import numpy as np


def _rz(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _rx(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1.0, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])


def _ry(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0, s, 0], [0, 1.0, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1]])


def _tr(x, z):
    T = np.eye(4)
    T[0, 3], T[2, 3] = x, z
    return T


def numpy_frames(robot, qq, dev):
    """The n + 1 frames (4, 4) of one pose qq (n,): the base, then the frame after each
    link, with MD-H deviations dev (n, 5); joint j turns about the z axis of frame j - 1."""
    table = robot.table.numpy() + dev
    pris = robot.prismatic.numpy().astype(bool)
    T = robot.base.numpy().copy()
    out = [T]
    for (th, d, a, al, be), qj, p in zip(table, qq, pris):
        T = T @ _rz(th + (0.0 if p else qj)) @ _tr(0.0, d + (qj if p else 0.0)) @ _tr(a, 0.0) @ _rx(al) @ _ry(be)
        out.append(T)
    return out


def numpy_fk(robot, q, dev, tool=None):
    """TCP positions (N, 3) mm of `robot` (its table, joint types, base, tool) with MD-H
    deviations dev (n, 5) [dtheta rad, dd mm, da mm, dalpha rad, dbeta rad] at q (N, n)
    rad (mm for a slide). tool: (4, 4) flange <- TCP replacing the robot's, or None."""
    tool = robot.tool.numpy() if tool is None else np.asarray(tool, dtype=float)
    return np.array([(numpy_frames(robot, qq, dev)[-1] @ tool)[:3, 3] for qq in np.asarray(q, dtype=float)])


def gravity_torques(robot, q, dev, masses, centres, payload_kg):
    """(N, n) gravity torque on each joint in kg mm (times g for N mm) at poses q (N, n):
    point masses `masses` (n,) kg at `centres` (n, 3) mm in the frames of links 1..n, and
    payload_kg (N,) at the TCP; tau_j = sum over the masses beyond joint j of
    ((c - o_j) x g) . z_j, g the robot's unit gravity vector."""
    g = robot.gravity.numpy()
    tool = robot.tool.numpy()
    out = np.zeros((len(q), robot.n))
    for i, qq in enumerate(np.asarray(q, dtype=float)):
        F = numpy_frames(robot, qq, dev)
        points = [(m, (F[k + 1] @ np.append(c, 1.0))[:3]) for k, (m, c) in enumerate(zip(masses, centres))]
        tcp = (F[-1] @ tool)[:3, 3]
        for j in range(robot.n):
            z, o = F[j][:3, 2], F[j][:3, 3]
            load = points[j:] + [(payload_kg[i], tcp)]
            out[i, j] = sum(m * np.dot(np.cross(c - o, g), z) for m, c in load)
    return out


def approach_signs(q):
    """(N, n) +1 / -1: the sign of each joint's last non-zero move into each row of q (N, n)
    in the order given, starting from all-zero joints (+1 before a joint first moves)."""
    q = np.asarray(q, dtype=float)
    prev, last = np.zeros(q.shape[1]), np.ones(q.shape[1])
    out = np.empty_like(q)
    for i, row in enumerate(q):
        step = np.sign(row - prev)
        last = np.where(step != 0, step, last)
        out[i], prev = last, row
    return out


def _rotvec(v):
    """Rotation matrix (3, 3) of a rotation vector v (3,) rad (Rodrigues)."""
    a = np.linalg.norm(v)
    if a == 0:
        return np.eye(3)
    k = v / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def physics_session(robot, q, seed, hidden, effect_mm=0.3, noise_mm=0.02):
    """A "real" robot with hidden physics, measured at q (N, n) rad in this order:
    seeded MD-H deviations (dd, da in +-0.5 mm; dtheta, dalpha, dbeta in +-0.02 deg), the
    effects named in `hidden` ("joint_compliance:J", "backlash:J", "gear_periodic:J",
    "base_frame"), each scaled to an RMS TCP displacement of effect_mm over these poses,
    and Gaussian noise. Returns (xyz (N, 3) mm, payload_kg (N,) uniform in [0, rated]).
    - joint_compliance: q_j += tau_j / K_j, tau_j the gravity torque of point masses of
      each link (0.5..3 x the rated payload, centres within 0.1 x the reach) and the payload;
    - backlash: q_j += s * (approach sign): the output ends past the mean position in the
      direction it last moved (the load runs on into the slack as the motor stops; a joint
      whose output trails the motor instead has the opposite sign);
    - gear_periodic: q_j += a1 sin(q_j + p1) + a2 sin(2 q_j + p2), random amplitudes, phases;
    - base_frame: the positions seen through a small rigid motion (rotation and shift)."""
    rng = np.random.default_rng(seed)
    n = robot.n
    q = np.asarray(q, dtype=float)
    dev = np.zeros((n, 5))
    dev[:, [1, 2]] = rng.uniform(-0.5, 0.5, (n, 2))
    dev[:, [0, 3, 4]] = np.radians(rng.uniform(-0.02, 0.02, (n, 3)))
    dev[:, 4] *= robot.has_beta.numpy()
    payload = rng.uniform(0.0, robot.payload_kg, len(q))
    nominal = numpy_fk(robot, q, dev)
    reach = np.abs(robot.table.numpy()[:, 1:3]).sum()

    def rms(d):
        return np.sqrt(np.mean(np.sum(d ** 2, -1)))

    dq, motion = np.zeros_like(q), np.zeros(6)  # joint offsets; base rotation vector and shift
    for spec in hidden:
        name, _, joints = spec.partition(":")
        js = [int(j) - 1 for j in joints.split(",")] if joints else []
        if name == "base_frame":
            v = rng.normal(size=6) * np.array([1e-4, 1e-4, 1e-4, 0.3, 0.3, 0.3])
            unit = rms(nominal @ _rotvec(v[:3]).T + v[3:] - nominal)
            motion += v * effect_mm / unit
            continue
        d = np.zeros_like(q)
        if name == "joint_compliance":
            masses = robot.payload_kg * rng.uniform(0.5, 3.0, n)
            centres = rng.uniform(-0.1, 0.1, (n, 3)) * reach
            d[:, js] = gravity_torques(robot, q, dev, masses, centres, payload)[:, js]
        elif name == "backlash":
            d[:, js] = approach_signs(q)[:, js]
        elif name == "gear_periodic":
            for j in js:
                a, p = rng.uniform(0.5, 1.0, 2), rng.uniform(0, 2 * np.pi, 2)
                d[:, j] = a[0] * np.sin(q[:, j] + p[0]) + a[1] * np.sin(2 * q[:, j] + p[1])
        else:
            raise ValueError(f"npsim: no physics for {spec!r}")
        d *= 1e-5 / np.abs(d).max()  # a small trial size, then scaled to effect_mm (linear at this size)
        dq += d * effect_mm / rms(numpy_fk(robot, q + d, dev) - nominal)
    xyz = numpy_fk(robot, q + dq, dev) @ _rotvec(motion[:3]).T + motion[3:]
    return xyz + rng.normal(0, noise_mm, xyz.shape), payload


def tracker_session(robot, q, seed, distance_mm=3000.0, reflector_mm=(0.0, 0.0, 290.0), sag_deg=0.05,
                    noise_mm=0.02, dev_scale=(0.2, 0.03)):
    """A "real" robot seen by a laser tracker: small seeded MD-H deviations (dev_scale:
    largest |dd|, |da| mm and |dtheta|, |dalpha| deg), a hidden joint-2 sag of sag_deg * cos(q2)
    (gravity-like, not an effect of the fitted model unless asked), a reflector
    `reflector_mm` on the flange instead of the robot's tool, a tracker frame turned and
    `distance_mm` away, Gaussian noise. q (N, n) rad -> xyz (N, 3) mm in the tracker frame."""
    rng = np.random.default_rng(seed)
    n = robot.n
    dev = np.zeros((n, 5))
    dev[:, [1, 2]] = rng.uniform(-1, 1, (n, 2)) * dev_scale[0]
    dev[:, [0, 3]] = np.radians(rng.uniform(-1, 1, (n, 2)) * dev_scale[1])
    q = np.asarray(q, dtype=float).copy()
    q[:, 1] = q[:, 1] + np.radians(sag_deg) * np.cos(q[:, 1])
    tool = np.eye(4)
    tool[:3, 3] = reflector_mm  # flange <- reflector
    p = numpy_fk(robot, q, dev, tool=tool)
    a = rng.uniform(0, 2 * np.pi)
    R = _rz(a)[:3, :3] @ _rx(np.radians(rng.uniform(-3, 3)))[:3, :3]
    t = np.array([distance_mm * np.cos(a), distance_mm * np.sin(a), -500.0])
    return p @ R.T + t + rng.normal(0, noise_mm, p.shape)


def reflectors_session(path, robot, n: int, points: dict, seed: int = 2, noise_mm: float = 0.01):
    """Write a measurement CSV (pose, q1..qN deg, x, y, z, point) of `robot` with MD-H
    deviations (+-0.05 deg, +-0.5 mm; the generator of `seed`) measured at n random poses
    (`torchcal.robots.poses.random_poses`, seed 3) at each reflector of `points` {id: (3,) mm
    offset on the flange}, in the robot's base frame, with noise_mm per axis. Returns (dev
    (n_joints, 5), q (n, n_joints) rad, {id: measured positions (n, 3) mm})."""
    from torchcal.robots.poses import random_poses

    rng = np.random.default_rng(seed)
    nj = robot.n
    dev = np.column_stack([rng.uniform(-1, 1, nj) * np.radians(0.05), rng.uniform(-1, 1, (nj, 2)) * 0.5,
                           rng.uniform(-1, 1, nj) * np.radians(0.05), np.zeros(nj)])
    q = random_poses(robot, n, 3).numpy()
    meas = {}
    with open(path, "w") as fh:
        fh.write("pose," + ",".join(f"q{k}" for k in range(1, nj + 1)) + ",x,y,z,point\n")
        for pid, off in points.items():
            T = np.eye(4)
            T[:3, 3] = off
            meas[pid] = numpy_fk(robot, q, dev, tool=T) + rng.normal(0, noise_mm, (n, 3))
            for i, (qq, p) in enumerate(zip(np.degrees(q), meas[pid])):
                fh.write(",".join(map(repr, [i + 1, *qq.tolist(), *p.tolist()])) + f",{pid}\n")
    return dev, q, meas


def thermal_session(robot, q, temp_c, seed, coefficient=2e-5, noise_mm=0.02):
    """A "real" robot whose link lengths grow with temperature, measured at q (N, n) rad
    and temp_c (N,) degC: every non-zero nominal length L (d, a) becomes
    L (1 + coefficient (temp_c - 20)) (one coefficient for all, 1/K), plus seeded MD-H
    deviations (dd, da in +-0.5 mm) and Gaussian noise. Returns xyz (N, 3) mm."""
    rng = np.random.default_rng(seed)
    n = robot.n
    q, temp_c = np.asarray(q, dtype=float), np.asarray(temp_c, dtype=float)
    dev = np.zeros((n, 5))
    dev[:, [1, 2]] = rng.uniform(-0.5, 0.5, (n, 2))
    lengths = robot.table.numpy()[:, 1:3]
    xyz = np.empty((len(q), 3))
    for i, (qi, t) in enumerate(zip(q, temp_c)):
        d = dev.copy()
        d[:, 1:3] += lengths * coefficient * (t - 20.0)
        xyz[i] = numpy_fk(robot, qi[None], d)[0]
    return xyz + rng.normal(0, noise_mm, xyz.shape)
