"""viz: look at a calibration instead of reading it.

Two kinds of output, both plain functions over numpy arrays or torch tensors (any device;
they are copied to host float64 once), so they depend on no other torchcal module than
`torchcal.errors` and `torchcal.io.files.atomic_write`:

- `viz.recording`: rerun recordings (``.rrd``), written to a file without a viewer (the
  file writer itself, `viz.recording_writer`, knows nothing of what is logged).
  Open one with ``rerun FILE.rrd``::

      from viz.recording import (RecordingWriter, log_workspace, log_residuals,
                                 log_error_intervals, log_discover_round, log_summary,
                                 summary_markdown)
      with RecordingWriter("run.rrd", seed=0) as rec:          # finalised and moved into
          log_workspace(rec, positions_mm, r_set, zones)        # place on exit
          log_residuals(rec, "before", measured_mm, model_before_mm)
          log_residuals(rec, "after", measured_mm, model_after_mm)
          log_error_intervals(rec, b_lo, b_hi, a_lo, a_hi, allowed_mm=1.0)
          log_summary(rec, summary_markdown("torchcal demo", {"RMS after (mm)": 0.21}))
          log_residual_vs_variables(rec, values, residual_mm, strengths,  # 2D scatter per
                                    correlates=["approach_q3"])          # variable

  The recording opens on a default blueprint laid out for what was logged (3D views of
  the workspace and residuals, time series, the summary).

- `viz.figures`: static PNGs (matplotlib Agg, no screen)::

      from viz import figures
      figures.zone_map("plots/zone_map.png", positions_mm, zones)            # 3 views
      figures.rset_histogram("plots/rset_hist.png", r_set)
      figures.error_intervals("plots/error_intervals.png", b_lo, b_hi, a_lo, a_hi)
      figures.residual_vs_joints("plots/residual_vs_joints.png", q_rad, residual_mm)

Units: positions and errors in mm, joint angles in rad in and degrees on the page.
Outputs are written atomically and are never replaced unless ``force=True``.
"""

from __future__ import annotations

import importlib

__all__ = ["figures", "recording", "recording_writer"]


def __getattr__(name: str):
    # Submodules load on first use: `import viz` stays cheap and does not import rerun.
    if name in __all__:
        return importlib.import_module(f"viz.{name}")
    raise AttributeError(f"module 'viz' has no attribute {name!r}")
