"""Convert one ipa-robot-accuracy UR10 series CSV into a torchcal measurement CSV.

Input: a measurement file of christianlandgraf/ipa-robot-accuracy (MIT licence,
Copyright (c) 2021 Christian Landgraf; Landgraf et al., "A Hybrid Neural Network Approach
for Increasing the Absolute Accuracy of Industrial Robots", IEEE CASE 2021), e.g.
Series_C/measurements_random_poses.csv: semicolon separated, decimal comma, columns
shoulder_pan_joint ... wrist_3_joint (rad), measurement_temperature (deg C),
measurement_x/_y/_z (mm, laser-tracker frame), measurement_rx/_ry/_rz (deg), each
measurement followed by a std column (dropped here).

Output: ``pose,q1,...,q6,x,y,z,rx,ry,rz,temp_c`` with q in degrees, x, y, z in mm,
rx, ry, rz in degrees as fixed-axis XYZ angles (R = Rz(rz) Ry(ry) Rx(rx)), temp_c in deg C,
one row per measurement in file order (the file order is the measurement order).

Euler convention of the source: measurement_rx/_ry/_rz are *intrinsic* XYZ angles,
R = Rx(rx) Ry(ry) Rz(rz) (equivalently fixed-axis ZYX). With that reading the measured
orientation equals nominal forward kinematics up to a constant base and tool rotation to
about 0.1 deg RMS; fixed-axis XYZ leaves 1.5-4.2 deg RMS.

Pose ids: rows whose commanded joints agree to within --tol rad (max over joints; default
1e-6) share a pose id, whether or not they are consecutive; ids are 0, 1, 2, ... in order of
first appearance. The ipa joint columns are not bit-identical on revisits: repeated targets
differ by 1e-5 to 3e-4 rad, so at the default no row of series B, C or D is a repeat; with
--tol 1e-3 series B has 293 and series D 31 repeated poses (series C none).

Usage: python convert_ipa.py [--tol RAD] IN.csv OUT.csv
"""

import argparse

import numpy as np

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
          "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
SAME_POSE_RAD = 1e-6


def read_ipa(path):
    """{column name: float array} from a semicolon-separated, decimal-comma file."""
    with open(path, encoding="utf-8-sig") as f:
        lines = [ln.strip() for ln in f if ln.strip()]
    header = [h.strip() for h in lines[0].split(";")]
    rows = [[float(c.strip().replace(",", ".")) for c in ln.split(";")] for ln in lines[1:]]
    table = np.array(rows, dtype=float)
    if table.ndim != 2 or table.shape[1] != len(header):
        raise ValueError(f"{path}: rows do not match the {len(header)} header columns")
    return {name: table[:, k] for k, name in enumerate(header)}


def rot(axis, a):
    """(N, 3, 3) rotations about 'x', 'y' or 'z' by angles a (rad)."""
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    m = {"x": [o, z, z, z, c, -s, z, s, c],
         "y": [c, z, s, z, o, z, -s, z, c],
         "z": [c, -s, z, s, c, z, z, z, o]}[axis]
    return np.stack(m, axis=-1).reshape(a.shape + (3, 3))


def fixed_xyz(R):
    """Angles (rx, ry, rz) in rad with R = Rz(rz) Ry(ry) Rx(rx); rx = 0 at gimbal lock."""
    ry = np.arctan2(-R[:, 2, 0], np.hypot(R[:, 0, 0], R[:, 1, 0]))
    lock = np.hypot(R[:, 0, 0], R[:, 1, 0]) < 1e-9
    rx = np.where(lock, 0.0, np.arctan2(R[:, 2, 1], R[:, 2, 2]))
    rz = np.where(lock, np.arctan2(-R[:, 0, 1], R[:, 1, 1]), np.arctan2(R[:, 1, 0], R[:, 0, 0]))
    return rx, ry, rz


def pose_ids(q, tol=SAME_POSE_RAD):
    """Integer id per row; rows with max |q - q'| <= tol share the id of the first such row."""
    ids, firsts = np.empty(len(q), dtype=int), []
    for r, qr in enumerate(q):
        near = np.flatnonzero(np.abs(q[firsts] - qr).max(axis=1) <= tol) if firsts else []
        if len(near):
            ids[r] = near[0]
        else:
            ids[r] = len(firsts)
            firsts.append(r)
    return ids


def convert(src, dst, tol=SAME_POSE_RAD):
    col = read_ipa(src)
    q = np.stack([col[j] for j in JOINTS], axis=1)
    a = np.radians([col["measurement_rx"], col["measurement_ry"], col["measurement_rz"]])
    R = rot("x", a[0]) @ rot("y", a[1]) @ rot("z", a[2])        # intrinsic XYZ (source)
    rx, ry, rz = np.degrees(fixed_xyz(R))                        # fixed-axis XYZ (output)
    pose = pose_ids(q, tol)
    out = np.column_stack([np.degrees(q), col["measurement_x"], col["measurement_y"],
                           col["measurement_z"], rx, ry, rz, col["measurement_temperature"]])
    header = ["pose"] + [f"q{k}" for k in range(1, 7)] + ["x", "y", "z", "rx", "ry", "rz", "temp_c"]
    with open(dst, "w", newline="\n") as f:
        f.write(",".join(header) + "\n")
        for p, row in zip(pose, out):
            f.write(",".join([str(p)] + [f"{v:.12g}" for v in row]) + "\n")
    n_pose = pose.max() + 1
    print(f"{src} -> {dst}: {len(pose)} rows, {n_pose} poses, "
          f"{len(pose) - n_pose} repeat measurements, "
          f"{np.sum(np.bincount(pose) > 1)} poses measured more than once")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description="ipa UR10 series CSV -> torchcal measurement CSV")
    ap.add_argument("src", metavar="IN.csv")
    ap.add_argument("dst", metavar="OUT.csv")
    ap.add_argument("--tol", type=float, default=SAME_POSE_RAD,
                    help="max joint difference (rad) of rows sharing a pose id (default 1e-6)")
    args = ap.parse_args()
    convert(args.src, args.dst, args.tol)
