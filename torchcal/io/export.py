"""``torchcal export``: the calibrated geometry of a model as a robot file, a URDF and/or an
MD-H table (CSV, `torchcal.io.mdh_table`), and what was written (`Export`).

The MD-H deviations go into the table, base_frame into the base, tool_offset into the tool
(`torchcal.calibration.geometry_only.calibrated_robot`; with several reflectors, one
offset each, the tool stays nominal and the robot file lists the offsets under "effects"). Other effects: with data the
geometry alone is refitted on them (`refit_geometry`) and that geometry exported; without,
they are listed in the robot file. A robot imported from a URDF keeps that file's links
(`torchcal.io.urdf.calibrated_urdf`), any other gets `minimal_urdf`; the URDF keeps the
robot's own base and tool (``tool0``) and carries the measuring frame and the reflector(s)
as separate fixed frames ``tracker`` and ``reflector`` (`torchcal.io.urdf.add_frames`).
Every output is checked before any work (OutputExistsError without `force`; never one of
the inputs or the files the model came from, `force` included; its folder must take a new
file) and written atomically.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from pathlib import Path

import torch

from torchcal.errors import InputError
from torchcal.robots.robot import Robot


@dataclass
class Export:
    """What ``torchcal export`` computed and wrote.

    Attributes:
        robot: the calibrated `Robot` of the robot file (geometry, base frame and tool offset
            folded in; its ``urdf`` names the written URDF when that URDF has the same chain).
        effects_not_held: [{"spec", "parameters"}] of the model's effects that a robot file, a
            URDF or an MD-H table cannot hold (listed in the robot file; empty after a refit).
        residual_stage_dropped: the model had a non-physical residual stage, which is not exported.
        refit: the `GeometryRefit` on `data` (the geometry alone refitted), else None.
        data_rows: rows of `data` refitted on (None: no refit; data are read only when the
            model has effects the exported robot cannot hold).
        urdf_source: the nominal URDF whose links the calibrated URDF keeps, None for a minimal URDF.
        written: {"robot_file", "urdf", "table"} paths written (None: not asked).
        urdf_links: {"base_link", "tip_link", "frames"} of the written URDF (its base and
            tool links, the names of its separate measuring frames), None without a URDF.
        zones: parameter sets of the model (a per-zone model of ``calibrate --partition``:
            its zones; 1 otherwise); a robot file, URDF or table holds one: the global one.
        zone1: the global parameters are zone 1's, which had poses (a file of the older
            interval-model format stores no global calibration: zone 1 stands in).
        reflectors: point ids of a model with several reflectors (one tool offset each):
            the robot file keeps the nominal tool and lists their offsets under "effects";
            empty otherwise.
    """

    robot: Robot
    effects_not_held: list
    residual_stage_dropped: bool
    refit: object
    data_rows: int | None
    urdf_source: str | None
    written: dict
    urdf_links: dict | None = None
    zones: int = 1
    zone1: bool = False
    reflectors: tuple = ()

    def to_dict(self) -> dict:
        r = self.refit
        return {"robot": self.robot.name, "joints": self.robot.n, "written": dict(self.written), "zones": self.zones,
                "zone1": self.zone1, "reflectors": list(self.reflectors),
                "effects_not_held": [e["spec"] for e in self.effects_not_held],
                "residual_stage_dropped": self.residual_stage_dropped,
                "urdf": None if self.urdf_links is None else dict(self.urdf_links, source=self.urdf_source),
                "refit": None if r is None else {"rows": self.data_rows, "dropped": list(r.dropped),
                                                 "refit_rms_mm": r.refit_rms_mm, "full_rms_mm": r.full_rms_mm,
                                                 "naive_rms_mm": r.naive_rms_mm, "status": str(r.fit.status)}}


def sources(im) -> list:
    """Paths the model `im` came from, as it records them: its data (provenance ``input``,
    ``partition``) and the URDF its robot was imported from."""
    out = [(im.provenance or {}).get(k) for k in ("input", "partition")]
    urdf = im.model.robot.urdf
    return [p for p in out + [urdf and urdf.get("path")] if p]


def not_the_nominal_robot(path, nominal: Robot) -> None:
    """InputError when `path` is an existing robot file of the model's nominal robot (the
    same joints, MD-H table, base, tool and limits, `robot_differences`): the robot file the
    model was fitted with. Writing the calibrated robot over it, ``--force`` or not, would
    lose the nominal, and every later fit with it would start from the calibrated geometry
    (a model does not record that file's path). Any other file, a robot file of a former
    export included, is left to `check_output`."""
    from torchcal.robots.checks import robot_differences
    from torchcal.io.robot_file import load_robot_file

    if not Path(path).is_file():
        return
    try:
        there = load_robot_file(path)
    except InputError:  # not a robot file
        return
    if not robot_differences(there, nominal):
        raise InputError(f"{path}: holds the nominal {nominal.name}, the robot the model was fitted with; "
                         f"refusing to write the calibrated robot over it, replace or not (give another file name)")


def export(im, *, robot_file=None, urdf=None, table=None, data=None, length_unit: str = "mm",
           angle_unit: str = "deg", force: bool = False, inputs=(), where: str = "model") -> Export:
    """Export the fitted model `im` (of a `ZonedFit` the global fit) as the
    outputs given (module doc); parameters beyond their plausible size get one
    `PlausibilityWarning` naming `where` (the model's file). data: `Measurements` or a measurement CSV path in
    `length_unit` / `angle_unit`, read only when the model has effects the exported robot
    cannot hold. inputs: paths never written over (the model's file, the data), beside
    the files the model came from (`sources`)."""
    from torchcal.calibration.geometry_only import calibrated_robot, measuring_frames, reflector_offsets, refit_geometry
    from torchcal.calibration.checks.model_data import check_measurements
    from torchcal.calibration.checks.ranges import payload_conditions, warn_outside_conditions
    from torchcal.calibration.checks.units import check_units
    from torchcal.calibration.checks.verdict import enforce
    from torchcal.calibration.plausibility import PlausibilityWarning, beyond_words
    from torchcal.io.files import all_or_none, atomic_write, check_output
    from torchcal.io.mdh_table import mdh_table_csv
    from torchcal.io.measurement_csv import as_measurements
    from torchcal.io.robot_file import write_robot_file
    from torchcal.io.urdf import add_frames, calibrated_urdf, minimal_urdf

    outs = {"robot_file": robot_file, "urdf": urdf, "table": table}
    if not any(outs.values()):
        raise InputError("export: give at least one output (robot file, URDF or MD-H table)")
    inputs = list(inputs) + sources(im)  # never over the files the model came from, force or not
    for p in outs.values():
        if p is not None:
            check_output(p, force=force, inputs=inputs)
    if robot_file is not None:
        not_the_nominal_robot(robot_file, im.model.robot)
    cm, theta = im.model, im.theta
    cal, rest = calibrated_robot(cm, theta)
    refit, rows = None, None
    if data is not None and rest:  # data only matter when the model has effects the robot cannot hold
        m = as_measurements(data, cm.robot, length_unit, angle_unit)
        check_units(m, cm.robot, length_unit=length_unit, angle_unit=angle_unit, where=m.source or "data")
        enforce(check_measurements(cm, theta.to(m.xyz), m, im.training_rms_mm, q_range=im.q_range))
        ranges = payload_conditions(im, m.payload_kg, m.source or "data", "evaluated at", stacklevel=3)
        warn_outside_conditions(ranges, {"temp_c": m.temp_c, "payload_kg": m.payload_kg}, "rows", stacklevel=3)
        rows, refit = len(m), refit_geometry(cm, theta, m, identified=im.report.free)
        cm, theta = refit.fit.model, refit.fit.theta
        cal, rest = calibrated_robot(cm, theta)[0], []
    beyond = beyond_words(cm, theta, im.plausible_limits)
    if beyond is not None:  # where the parameters leave torchcal for a controller: said once more
        warnings.warn(PlausibilityWarning(
            f"{where}: exported parameters beyond their plausible size: {beyond}; the exported robot carries them "
            "(a value edited by hand, or a fit that absorbed something else: check before a controller uses it)"),
            stacklevel=3)
    urdf_text, urdf_info, source, links = None, None, None, None
    if urdf is not None:  # the robot's own base and tool; the measuring set-up as separate frames
        own = calibrated_robot(cm, theta, fold=False)[0]
        W, reflectors = measuring_frames(cm, theta)
        if own.urdf is not None:
            urdf_text, tip = calibrated_urdf(im.model.robot, own)
            source, base_link = own.urdf["path"], own.urdf["base_link"]
        else:
            urdf_text, tip, base_link = minimal_urdf(own), "tool0", "base_link"
        urdf_text = add_frames(urdf_text, base_link, tip, W, reflectors)
        urdf_info = {"path": str(Path(urdf).resolve()), "base_link": base_link, "tip_link": tip}
        links = dict(urdf_info, frames=(["tracker"] if W is not None else []) + [n for n, _ in reflectors])
        if W is not None or reflectors:  # the robot file folds the frames in: its URDF chain is another
            urdf_info = None
    cal = dataclasses.replace(cal, urdf=urdf_info)  # the calibrated robot file points at the calibrated URDF
    with all_or_none(outs.values()):  # a failure or Ctrl-C between them leaves none of the new files
        if robot_file is not None:  # several reflectors: listed beside the effects it cannot hold
            write_robot_file(robot_file, cal, effects=rest + reflector_offsets(cm, theta), force=force, inputs=inputs)
        if urdf is not None:
            atomic_write(urdf, urdf_text, force=force, inputs=inputs)
        if table is not None:
            atomic_write(table, mdh_table_csv(cal), force=force, inputs=inputs)
    points = next((tuple(e.points) for e in cm.effects if e.name == "tool_offset"), ())
    return Export(cal, rest, im.residual_model is not None, refit, rows, source,
                  {k: (None if v is None else str(v)) for k, v in outs.items()}, links if urdf else None,
                  int(im.zone_theta.shape[0]), _zone1_stands_in(im), points)


def _zone1_stands_in(im) -> bool:
    """The global parameters of a per-zone model are its zone 1's, a zone with poses (fitted
    on its own, it is not the global fit): a file of the older interval-model format."""
    zones = getattr(im, "zones", None)
    return bool(zones) and len(zones) > 1 and bool(im.zone_poses and im.zone_poses[0]) and \
        bool(torch.equal(im.theta, zones[0].theta))
