"""`fit()` of this tree against the fit of another tree (a commit before a refactoring).

Usage: python benchmarks/fit_equivalence.py /path/to/other/tree

Fits, in this process and in a subprocess with PYTHONPATH=the other tree, the same cases
and prints per case the largest relative difference of the fitted parameters
(``|a - b| / max(|b|, 1e-300)`` over the parameters, and ``max |a - b| / max |b|``), of the
standard errors, the held names, the iteration count and the status:

- ur10-frame, ur10-gear-compliance: examples/ur10/series_c.csv, the training split of
  `torchcal split --fraction 0.6 --seed 0` (positions and orientations), effects
  `base_frame tool_offset` and `base_frame tool_offset gear_periodic:2 joint_compliance:2`;
- huber, cauchy: a simulated kr1000titan (seed 11), 240 poses, 2 % of the rows moved by
  5 mm, robust Huber / Cauchy fits;
- tracker: a UR10 seen by a tracker 3 m away with a 290 mm reflector (the plain-numpy
  simulator of tests/npsim.py), positions only, `base_frame tool_offset` (registration,
  the cold-start identifiability check).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
FRAME = ["base_frame", "tool_offset"]


def cases():
    """{name: (model, ctx, xyz, fit keywords)}, built in whichever tree is imported."""
    import torchcal
    from torchcal.calibration.model import CalibrationModel
    from torchcal.effects import context_of
    from torchcal.io.measurement_csv import read_measurements
    from torchcal.measurements import Measurements, split_by_pose
    from torchcal.robots.poses import random_poses
    from torchcal.simulation.virtual_robot import VirtualRobot

    out = {}
    ur10 = torchcal.robot(ROOT / "examples" / "ur10" / "ur10.json")
    c = read_measurements(ROOT / "examples" / "ur10" / "series_c.csv", robot=ur10)
    c = c.subset(split_by_pose(c.pose, 0.6, 0))
    for name, effects in (("ur10-frame", FRAME), ("ur10-gear-compliance", FRAME + ["gear_periodic:2",
                                                                                   "joint_compliance:2"])):
        model = CalibrationModel.for_measurements(ur10, effects, c)
        out[name] = (model, context_of(ur10, c), c.xyz, dict(pose=c.pose, rotation=c.rotation))

    kr = torchcal.robot("kr1000titan")
    m = VirtualRobot(kr, [], seed=11).measure(random_poses(kr, 240, torch.Generator().manual_seed(12)), noise_mm=0.02)
    g = torch.Generator().manual_seed(13)
    rows = torch.randperm(240, generator=g)[:5]
    d = torch.randn(5, 3, generator=g, dtype=torch.float64)
    xyz = m.xyz.clone()
    xyz[rows] += 5.0 * d / d.norm(dim=-1, keepdim=True)
    for loss in ("huber", "cauchy"):
        out[loss] = (CalibrationModel(kr), context_of(kr, m), xyz, dict(robust=loss, pose=m.pose))

    sys.path.insert(0, str(ROOT / "tests"))
    from npsim import tracker_session

    q = random_poses(ur10, 120, torch.Generator().manual_seed(1))
    t = Measurements(torch.arange(120), q, torch.as_tensor(tracker_session(ur10, q.numpy(), seed=2)))
    out["tracker"] = (CalibrationModel(ur10, FRAME), context_of(ur10, t), t.xyz, dict(pose=t.pose))
    return out


def run(path: str) -> None:
    """Fit every case and save theta, std, n_iter, status, held to `path` (.npz + .json)."""
    from torchcal.calibration.fit import fit

    arrays, facts = {}, {}
    for name, (model, ctx, xyz, kw) in cases().items():
        t0 = time.process_time()
        res = fit(model, ctx, xyz, **kw)
        arrays[name + ":theta"] = res.theta.numpy()
        arrays[name + ":std"] = res.std.numpy()
        facts[name] = {"n_iter": res.n_iter, "status": res.status, "held": res.report.held,
                       "cpu_s": time.process_time() - t0}
    np.savez(path, **arrays)
    Path(path + ".json").write_text(json.dumps(facts))


def rel(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(max_i |a_i - b_i| / |b_i| over b_i != 0 (and a_i != b_i where b_i = 0: inf), max|a - b| / max|b|)."""
    d = np.abs(a - b)
    nz = b != 0
    elem = max(float((d[nz] / np.abs(b[nz])).max(initial=0.0)), float("inf") if (d[~nz] > 0).any() else 0.0)
    return elem, float(d.max(initial=0.0) / max(np.abs(b).max(initial=0.0), 1e-300))


def main() -> None:
    other = sys.argv[1]
    with tempfile.TemporaryDirectory() as tmp:
        here, there = os.path.join(tmp, "here.npz"), os.path.join(tmp, "there.npz")
        env = dict(os.environ, PYTHONPATH=other)
        subprocess.run([sys.executable, __file__, "--dump", there], env=env, check=True)
        run(here)
        a, b = np.load(here), np.load(there)
        fa, fb = json.loads(Path(here + ".json").read_text()), json.loads(Path(there + ".json").read_text())
    print(f"{'case':<22} {'theta rel (elem / max)':>24} {'std rel (elem / max)':>24}  same held, n_iter, status; cpu s")
    for name in fa:
        t, s = rel(a[name + ":theta"], b[name + ":theta"]), rel(a[name + ":std"], b[name + ":std"])
        same = [fa[name][k] == fb[name][k] for k in ("held", "n_iter", "status")]
        print(f"{name:<22} {t[0]:>11.2e} / {t[1]:<10.2e} {s[0]:>11.2e} / {s[1]:<10.2e}  {same}; "
              f"{fa[name]['cpu_s']:.1f} vs {fb[name]['cpu_s']:.1f}")


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--dump":
        run(sys.argv[2])
    else:
        main()
