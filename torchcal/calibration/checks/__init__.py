"""Input checks against a robot or a model, one module a kind of check: data, targets or a
partition that cannot belong to the robot or model given, and a fit that explains nothing.

The one place for checks of whether inputs fit a robot or a model (docs/design.md); the
readers of `torchcal.io` check a file's own content (cells, columns, joint limits), and
`torchcal.robots.checks` a robot's own numbers (lengths and angles in another unit) and
whether two robots are the same (and mounted alike, for a model's gravity-driven effects).

A fitted model applied to measurements of another robot, to measurements taken in a
measuring frame that moved since the fit, or to numbers in the wrong unit gives errors
of hundreds of mm; without a check the user reads "rms 1203 mm" and goes on. The checks
turn that into one line naming the likely cause (docs/registration.md).

- `verdict`: the `Mismatch` a check finds, `MismatchWarning`, the gross bound (GROSS_MM)
  and `enforce` (a refusal, or a warning where the command goes on);
- `units`: measurements in another length or angle unit, judged by their spread;
- `model_data`: measurements against a fitted model (evaluate, register, export, diagnose),
  rows far beyond its training rms that another reflector, swapped point ids or a slightly
  moved instrument explain;
- `robot_data`: measurements against the nominal robot before a fit, and a fit's own
  residuals after it;
- `nominal_data`: positions that agree with the nominal robot (computed, not measured);
- `frame_fit`: the nominal robot in its best measuring frame and with its best tool
  offset, what `robot_data` and `sessions` judge by;
- `columns`: joint columns mixed up, positions misaligned with the joint values;
- `sessions`: two measuring frames in one file (two sessions joined, an instrument moved
  or a reflector changed midway), rows repeated from another session, a transfer session
  that is the other part of a split of the data;
- `orientation`: rx, ry, rz in another convention or unit;
- `orientation_frame`: rx, ry, rz in another frame than x, y, z;
- `row_order`: rows re-ordered after the session, for an effect that reads the order;
- `targets`: compensation targets out of reach, in another unit or frame, their seeds,
  the conditions they lack;
- `partition`: a partition of another robot, positions beyond its sweep;
- `ranges`: rows beyond the calibrated joint range or the fitted conditions, no payload
  given to a model fitted on loads.
"""
