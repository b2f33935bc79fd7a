"""The facts of a calibration report (``torchcal report``; the HTML is `viz.report`).

`calibration_report` gathers, for a fitted or discovered MODEL.json and optionally
held-out measurements and discover's ``--json`` history:

- provenance: each input file's path, size, SHA-256 and modification time (UTC);
- the model file as written (effects, parameters with std / ci95 and any label the file
  carries, what is held, the base frame, the fit), each effect's physics in words (`effect_physics`);
- on the held-out rows: the errors of the calibrated model (`torchcal.api.evaluate`) and,
  as "before", of the nominal robot in the best measuring frame (`torchcal.api.register`
  of the nominal robot on these rows: base frame, and tool offset when the model fits
  one), each as `torchcal.metrics.error_summary`, `iso9283` and, with a tolerance,
  `tolerance_verdict`; what the calibrated model leaves learnable on these rows
  (`torchcal.diagnosis.unexplained`);
- for a per-zone model of ``torchcal calibrate`` (a `ZonedFit`, the paper's pipeline): each row
  predicted by its zone's center parameters, and the paper's Table 5 on the held-out
  poses (`zone_table`: per-axis error intervals and R_set before and after, per pose);
- discover's rounds, refits, verdicts and reasons, its unexplained section and its
  transfer check when the history holds one (read as written).
"""

from __future__ import annotations

import datetime
import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import torch

from torchcal.errors import InputError

__all__ = ["CalibrationReport", "calibration_report", "effect_physics", "file_facts", "zone_table"]


def file_facts(path) -> dict:
    """{"path", "name", "bytes", "sha256", "modified_utc"} of a file."""
    p = Path(path)
    data = p.read_bytes()
    mtime = datetime.datetime.fromtimestamp(p.stat().st_mtime, datetime.timezone.utc)
    return {"path": str(p), "name": p.name, "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest(),
            "modified_utc": mtime.strftime("%Y-%m-%d %H:%M:%S UTC")}


def effect_physics(spec: str) -> str:
    """The physics of an effect spec in words: the first paragraph of its class's docstring,
    or of its module's ("" for an unknown name), without the leading "`name`: "."""
    import sys

    import torchcal.effects  # noqa: F401  (registers the built-in effects)
    from torchcal.effects.registry import REGISTRY

    cls = REGISTRY.get(spec.split(":")[0])
    if cls is None:
        return ""
    doc = (cls.__doc__ or getattr(sys.modules.get(cls.__module__), "__doc__", None) or "").strip()
    text = " ".join(doc.split("\n\n")[0].split())
    return text.split("`: ", 1)[1] if text.startswith("`") and "`: " in text else text


@dataclass
class CalibrationReport:
    """What `calibration_report` found (module doc); `to_dict` is its JSON.

    model: the MODEL.json object; files: {"model", "data", "history"} file facts (None
    when not given); effects: [(spec, physics in words)]; held-out figures (None without
    data): after / before (`error_summary`), iso_after / iso_before (`iso9283`),
    verdict_after / verdict_before (`tolerance_verdict`, None without a tolerance);
    outside_range: held-out rows outside the calibrated joint range; data_warnings:
    the text of evaluate's warnings about the held-out rows, carried into the report
    (`ConditionRangeWarning`: a temperature or payload outside the range the model's
    effects were fitted on; `PayloadAssumedWarning`: no payload column for a model fitted
    on loads; `ReflectorWarning`: rows measured at another point of the tool;
    `MismatchWarning`: another point id, another orientation convention, an instrument
    moved a little since the fit, rows beyond a partition's sweep; [] when none);
    zones: the paper's Table 5 on the held-out poses for a model of ``calibrate``
    (`zone_table`, else None);
    history: discover's JSON (None when not given). Per row, for the figures (not in
    `to_dict`): data (`Measurements`), robot (the model's nominal `Robot`),
    residuals_after / residuals_before (N, 3) mm measured - model, unexplained
    (`Unexplained` of the calibrated model on the rows)."""

    model: dict
    files: dict
    effects: list
    created_utc: str
    tolerance_mm: float | None = None
    after: dict | None = None
    before: dict | None = None
    before_model: str = ""
    iso_after: dict | None = None
    iso_before: dict | None = None
    verdict_after: dict | None = None
    verdict_before: dict | None = None
    outside_range: int | None = None
    data_warnings: list = field(default_factory=list)
    history: dict | None = None
    zones: list | None = None
    data: object = field(default=None, repr=False)
    robot: object = field(default=None, repr=False)
    residuals_after: torch.Tensor | None = field(default=None, repr=False)
    residuals_before: torch.Tensor | None = field(default=None, repr=False)
    unexplained: object = field(default=None, repr=False)

    def to_dict(self) -> dict:
        out = {"created_utc": self.created_utc, "files": self.files, "robot": self.model.get("robot"),
               "effects": [{"spec": s, "physics": p} for s, p in self.effects], "tolerance_mm": self.tolerance_mm}
        if self.after is not None:
            out["held_out"] = {"after": self.after, "before": self.before, "before_model": self.before_model,
                               "iso9283_after": self.iso_after, "iso9283_before": self.iso_before,
                               "verdict_after": self.verdict_after, "verdict_before": self.verdict_before,
                               "outside_range": self.outside_range, "data_warnings": self.data_warnings,
                               "zone_table": self.zones,
                               "unexplained": self.unexplained.to_dict() if self.unexplained is not None else None}
        return out


def check_history_of(history: dict, model, history_path, model_path) -> None:
    """InputError (one line naming both files) when the discover history's final effects
    are not the effects of `model` (a `CalibrationModel`; compared as parsed specs, in any
    order): the history of another model would describe, in the report, a search that did
    not make it (a history without final effects is not judged)."""
    from torchcal.effects.spec import parse_specs

    final = history.get("final_effects")
    if not isinstance(final, list):
        return
    try:
        theirs = sorted(str(e) for e in parse_specs([str(e) for e in final], model.robot.n))
    except InputError:
        theirs = sorted(str(e) for e in final)  # not this robot's joints: not the model's either
    ours = sorted(model.specs())
    if theirs != ours:
        raise InputError(f"{history_path}: a discover history whose final effects [{', '.join(map(str, final))}] "
                         f"are not those of {model_path} [{', '.join(model.specs()) or 'geometric only'}]: the "
                         "history of another model; give the history of the discover that wrote this model")


def calibration_report(model_path, data=None, *, history_path=None, tolerance_mm: float | None = None,
                       length_unit: str = "mm", angle_unit: str = "deg") -> CalibrationReport:
    """The `CalibrationReport` of the MODEL.json at model_path (``torchcal fit`` /
    ``discover --out``), on held-out measurements `data` (a CSV path or `Measurements`,
    optional; the model's own training file, by its SHA-256, is refused: the figures are
    held-out ones), with discover's history JSON at history_path (optional) and a distance
    tolerance in mm (optional, > 0)."""
    from torchcal.io.files import read_json
    from torchcal.io.measurement_csv import read_measurements
    from torchcal.measurements import Measurements

    if tolerance_mm is not None and not tolerance_mm > 0:
        raise InputError(f"tolerance_mm: expected a distance > 0 mm, got {tolerance_mm}")
    from torchcal import api
    from torchcal.io import modelfile

    model = read_json(model_path, "model file")
    if model.get("format") == modelfile.FORMAT_INTERVAL:  # the older file of calibrate: in today's layout
        model = modelfile.to_dict(modelfile.load(model_path))
    if not str(model.get("format", "")).startswith("torchcal-model/"):
        raise InputError(f"{model_path}: not a MODEL.json of `torchcal fit`, `discover` or `calibrate` "
                         f"(format {model.get('format')!r})")
    fitted = api.load(model_path)  # the model read as every command reads it: a value NaN, a bad block refused
    history = None
    if history_path is not None:
        history = read_json(history_path, "discover history")
        if not isinstance(history, dict) or "history" not in history:
            raise InputError(f"{history_path}: not a history JSON of discover (no 'history' key)")
        check_history_of(history, fitted.model, history_path, model_path)
    files = {"model": file_facts(model_path), "data": None,
             "history": file_facts(history_path) if history_path is not None else None}
    specs = [str(s) for s in model.get("effects", [])]
    rep = CalibrationReport(model, files, [(s, effect_physics(s)) for s in specs],
                            datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
                            tolerance_mm=tolerance_mm, history=history)
    if data is None:
        return rep
    m = data if isinstance(data, Measurements) else read_measurements(
        data, robot=fitted.model.robot, length_unit=length_unit, angle_unit=angle_unit)
    source = data if isinstance(data, (str, Path)) else m.source
    if source is not None and Path(source).is_file():
        files["data"] = file_facts(source)
        trained = (model.get("provenance") or {}).get("input_sha256")
        if trained is not None and files["data"]["sha256"] == trained:
            raise InputError(f"{source}: the data the model was fitted on (SHA-256 as its provenance records "
                             f"for {(model.get('provenance') or {}).get('input')}): the report's accuracy is on "
                             "held-out poses; give measurements the fit did not see (a split of the session, "
                             "another session)")
    _held_out(rep, fitted, m, {s.split(":")[0] for s in specs}, tolerance_mm)
    return rep


def _held_out(rep: CalibrationReport, fitted, m, effects: set, tolerance_mm) -> None:
    """The held-out figures of `rep` (module doc) on measurements m; fitted: a `FitResult`
    (of a `ZonedFit` also the paper's Table 5, `zone_table`)."""
    import warnings

    from torchcal import api
    from torchcal.calibration.checks.model_data import ReflectorWarning
    from torchcal.calibration.checks.ranges import PayloadAssumedWarning
    from torchcal.calibration.checks.verdict import MismatchWarning
    from torchcal.calibration.joint_range import CalibratedRangeWarning, ConditionRangeWarning
    from torchcal.calibration.zone_calibration import ZonedFit
    from torchcal.diagnosis.unexplained import unexplained
    from torchcal.metrics import error_summary, iso9283, pose_groups, tolerance_verdict

    robot = fitted.model.robot
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("ignore", CalibratedRangeWarning)  # counted in outside_range
        warnings.simplefilter("always", ConditionRangeWarning)  # carried into the report, and passed on
        warnings.simplefilter("always", PayloadAssumedWarning)
        warnings.simplefilter("always", ReflectorWarning)
        warnings.simplefilter("always", MismatchWarning)
        ev = api.evaluate(fitted, m)  # a ZonedFit: each row with its zone's parameters
    for w in caught:  # every other warning (and this one) reaches the caller as evaluate gave it
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    carried = (ConditionRangeWarning, PayloadAssumedWarning, ReflectorWarning, MismatchWarning)
    rep.data_warnings = [str(w.message) for w in caught if issubclass(w.category, carried)]
    err, rep.outside_range = ev.residuals_mm, ev.outside_range
    zone = fitted.assign(robot.fk(m.q)) if isinstance(fitted, ZonedFit) else None
    if "base_frame" in effects:  # the data are in the instrument's frame: the nominal robot in its best frame
        tool = "tool_offset" in effects
        from torchcal.calibration.registration import TransferWarning

        with warnings.catch_warnings():  # the baseline is judged on these rows only
            warnings.simplefilter("ignore", TransferWarning)
            err0 = api.evaluate(api.register(robot, m, tool=tool), m).residuals_mm
        rep.before_model = "nominal robot, base frame" + (" and tool offset" if tool else "") + " fitted on these rows"
    elif "tool_offset" in effects:  # robot base frame, the reflector(s) where the model puts them
        err0 = _nominal_with_tool(robot, m)
        rep.before_model = "nominal robot, tool offset" + (" per reflector" if m.point is not None and
                                                            len(set(m.point.tolist())) > 1 else "") + \
            " fitted on these rows"
    else:  # the data are in the robot's base frame, as the model assumes
        err0 = (m.xyz - robot.fk(m.q)).detach()
        rep.before_model = "nominal robot (its MD-H table, base and tool as given)"
    group, keys = pose_groups(m.pose, m.point)
    rep.data, rep.robot = m, robot
    rep.residuals_after, rep.residuals_before = err, err0
    rep.after, rep.before = error_summary(err), error_summary(err0)
    rep.iso_after, rep.iso_before = iso9283(err, group, keys), iso9283(err0, group, keys)
    if tolerance_mm is not None:
        rep.verdict_after = tolerance_verdict(err.norm(dim=-1), group, tolerance_mm, keys)
        rep.verdict_before = tolerance_verdict(err0.norm(dim=-1), group, tolerance_mm, keys)
    if zone is not None:
        rep.zones = zone_table(m, err0, err, zone, tolerance_mm)
    if len(m) >= 10:
        rep.unexplained = unexplained(robot, m, err, seed=0)


def _nominal_with_tool(robot, m) -> torch.Tensor:
    """(N, 3) mm measured - model of the nominal robot whose tool offset (one per point id)
    is fitted alone on the measurements m (robot base frame): the "before" of a model with
    tool_offset and no base_frame."""
    from torchcal.calibration.fit import fit
    from torchcal.calibration.model import CalibrationModel
    from torchcal.effects import context_of

    cm = CalibrationModel.for_measurements(robot, ["tool_offset"], m)
    free = torch.zeros(cm.n_params, dtype=torch.bool)
    free[cm.slices[1]] = True
    ctx = context_of(robot, m)
    res = fit(cm, ctx, m.xyz, free=free, pose=m.pose, register=False, prior=False, posterior=False)
    return (m.xyz - cm.predict(res.theta, ctx)).detach()


def zone_table(m, before_mm: torch.Tensor, after_mm: torch.Tensor, zone: torch.Tensor,
               tolerance_mm: float | None) -> list:
    """The paper's Table 5 on held-out poses: per pose (in order of first appearance) its
    zone and, before and after, the per-axis interval [min, max] over its rows of
    measured - model (mm) and, with a tolerance T, R_set of each axis interval against
    [-T, T] and of the distance interval [0, max |e|] against [0, T]
    (`torchcal.reliability.r_set`).

    before_mm, after_mm: (N, 3) mm errors per row; zone: (N,) zone per row.
    Returns [{"pose", "zone", "rows", "before": {"lower", "upper", "r_set"}, "after": ...}]
    with lower, upper [x, y, z] mm and r_set [x, y, z, distance] (None without tolerance)."""
    from torchcal.metrics import pose_groups
    from torchcal.reliability import r_set

    group, keys = pose_groups(m.pose)
    G = len(keys)
    first = torch.full((G,), len(m), dtype=torch.int64).scatter_reduce(0, group, torch.arange(len(m)), "amin")
    out = [{"pose": keys[g], "zone": int(zone[first[g]]), "rows": int((group == g).sum())} for g in range(G)]
    for name, e in (("before", before_mm), ("after", after_mm)):
        e = e.detach().to("cpu", torch.float64)
        lo = torch.full((G, 3), float("inf"), dtype=e.dtype).scatter_reduce(0, group[:, None].expand(-1, 3), e, "amin")
        hi = torch.full((G, 3), -float("inf"), dtype=e.dtype).scatter_reduce(0, group[:, None].expand(-1, 3), e, "amax")
        rs = None
        if tolerance_mm is not None:
            dist = torch.zeros(G, dtype=e.dtype).scatter_reduce(0, group, e.norm(dim=-1), "amax")
            rs = torch.cat([r_set((-tolerance_mm, tolerance_mm), (lo, hi)),
                            r_set((0.0, tolerance_mm), (torch.zeros_like(dist), dist))[:, None]], dim=1)
        for g in range(G):
            out[g][name] = {"lower": lo[g].tolist(), "upper": hi[g].tolist(),
                            "r_set": rs[g].tolist() if rs is not None else None}
    return out
