"""`torchcal report` and `torchcal.metrics`: the figures against plain numpy, the HTML
self-contained, rendered by headless Chromium (skipped, with the reason, without it)."""

import html
import json
import re
import shutil
import subprocess

import numpy as np
import pytest
import torch

from torchcal.cli import main
from torchcal.metrics import error_summary, iso9283, pose_groups, tolerance_verdict

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


# --------------------------------------------------------------------------- metrics
def test_error_summary_matches_numpy():
    rng = np.random.default_rng(3)
    e = rng.normal(0.1, 0.3, size=(257, 3))
    s = error_summary(torch.tensor(e))
    d = np.linalg.norm(e, axis=1)
    assert s["n"] == 257
    assert s["mean_mm"] == pytest.approx(d.mean()) and s["rms_mm"] == pytest.approx(np.sqrt((d ** 2).mean()))
    assert s["p95_mm"] == pytest.approx(np.percentile(d, 95)) and s["max_mm"] == pytest.approx(d.max())
    for k, a in enumerate("xyz"):
        c = e[:, k]
        assert s["axes"][a]["bias_mm"] == pytest.approx(c.mean())
        assert s["axes"][a]["rms_mm"] == pytest.approx(np.sqrt((c ** 2).mean()))
        assert s["axes"][a]["p95_mm"] == pytest.approx(np.percentile(np.abs(c), 95))
        assert s["axes"][a]["max_mm"] == pytest.approx(np.abs(c).max())


def _iso_numpy(e, pose):
    """ISO 9283 AP and RP per pose, written out from the standard's formulas."""
    out = {}
    for p in dict.fromkeys(pose.tolist()):
        x = e[pose == p]
        bary = x.mean(axis=0)
        ap = float(np.sqrt(((bary) ** 2).sum()))
        lj = np.sqrt(((x - bary) ** 2).sum(axis=1))
        rp = float(lj.mean() + 3 * np.sqrt(((lj - lj.mean()) ** 2).sum() / (len(x) - 1))) if len(x) >= 3 else None
        out[p] = (len(x), ap, rp)
    return out


def test_iso9283_matches_the_standards_formulas():
    rng = np.random.default_rng(7)
    counts = [1, 2, 3, 5, 30]  # a pose once, twice (no RP), and with repeats
    pose = np.repeat(np.array([11, 4, 9, 2, 7]), counts)
    offset = rng.normal(0, 0.2, size=(5, 3))
    e = np.repeat(offset, counts, axis=0) + rng.normal(0, 0.02, size=(len(pose), 3))
    group, keys = pose_groups(torch.tensor(pose))
    assert keys == [11, 4, 9, 2, 7] and group.tolist() == np.repeat(np.arange(5), counts).tolist()
    got = iso9283(torch.tensor(e), group, keys)
    want = _iso_numpy(e, pose)
    assert got["poses"] == 5 and got["poses_with_repeats"] == 3 and got["cycles"] == {"min": 1, "max": 30}
    for row in got["per_pose"]:
        n, ap, rp = want[row["pose"]]
        assert row["n"] == n and row["ap_mm"] == pytest.approx(ap)
        assert (row["rp_mm"] is None) == (rp is None) and (rp is None or row["rp_mm"] == pytest.approx(rp))
    rps = [v[2] for v in want.values() if v[2] is not None]
    assert got["rp_mm"]["max"] == pytest.approx(max(rps)) and got["ap_mm"]["max"] == pytest.approx(
        max(v[1] for v in want.values()))


def test_pose_groups_keep_reflectors_apart():
    pose = torch.tensor([5, 5, 5, 5, 3, 3])
    point = torch.tensor([1, 2, 1, 2, 1, 1])
    group, keys = pose_groups(pose, point)
    assert keys == [(5, 1), (5, 2), (3, 1)] and group.tolist() == [0, 1, 0, 1, 2, 2]


def test_tolerance_verdict_per_pose():
    d = torch.tensor([0.2, 0.9, 0.3, 1.4, 0.5, 0.5])  # pose 8 has one row beyond 1 mm
    group, keys = pose_groups(torch.tensor([7, 7, 8, 8, 9, 9]))
    v = tolerance_verdict(d, group, 1.0, keys)
    assert not v["passed"] and v["poses_failed"] == 1 and v["rows_failed"] == 1
    assert v["failed"] == [{"pose": 8, "max_mm": pytest.approx(1.4)}]
    assert tolerance_verdict(d, group, 1.5, keys)["passed"]


# --------------------------------------------------------------------------- the command
@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A simulated robot with compliance the geometric model lacks; training poses and
    held-out poses measured 3 times each; fit and discover on the training poses."""
    d = tmp_path_factory.mktemp("report")
    sim = ["simulate", "--robot", "ur5e", "--effects", "base_frame", "joint_compliance:2,3", "--n", "60",
           "--repeats", "3", "--noise", "0.02", "--seed", "1"]
    assert main(sim + ["--out", str(d / "train.csv")]) == 0
    assert main(sim + ["--pose-seed", "2", "--out", str(d / "val.csv")]) == 0
    assert main(["fit", str(d / "train.csv"), "--robot", "ur5e", "--effects", "base_frame",
                 "--out", str(d / "fit.json")]) == 0
    assert main(["discover", str(d / "train.csv"), "--robot", "ur5e", "--effects", "base_frame",
                 "--out", str(d / "disc.json"), "--json", str(d / "hist.json")]) == 0
    return d


@pytest.fixture(scope="module")
def report(session):
    d = session
    out = d / "report.html"
    assert main(["report", str(d / "disc.json"), "--data", str(d / "val.csv"), "--history", str(d / "hist.json"),
                 "--tolerance-mm", "0.1", "--out", str(out), "--json", str(d / "report.json")]) == 0
    return out


def test_report_is_self_contained_and_complete(report, session):
    text = report.read_text()
    assert not re.search(r"https?://", text), "a URL in the report"
    assert "<script" not in text.lower() and "@import" not in text and "url(" not in text
    imgs = re.findall(r'<img [^>]*src="([^"]+)"', text)
    assert len(imgs) >= 4 and all(s.startswith("data:image/png;base64,") for s in imgs)
    for h in ("1. Provenance", "2. The model", "3. Accuracy on the held-out poses", "4. Verdict per pose",
              "5. Discovery rounds", "6. What stays learnable", "@page", "max-width: 100%"):
        assert h in text, h
    js = json.loads((session / "report.json").read_text())
    held = js["held_out"]
    # the calibrated model beats the nominal robot on poses it never saw
    assert held["after"]["rms_mm"] < held["before"]["rms_mm"]
    # 3 repeats per pose: repeatability is computed for every pose, from noise alone (0.02 mm per axis)
    iso = held["iso9283_after"]
    assert iso["poses_with_repeats"] == iso["poses"] == 60 and 0.02 < iso["rp_mm"]["mean"] < 0.2
    # the printed verdict is the JSON's, and the HTML shows it
    v = held["verdict_after"]
    assert ("PASS:" if v["passed"] else "FAIL:") in text
    assert f"{v['poses'] - v['poses_failed']} of {v['poses']} held-out poses within 0.1 mm" in text
    hist = json.loads((session / "hist.json").read_text())
    for r in hist["history"]:
        for c in (r.get("step") or {}).get("refits", []):
            assert c["candidate"] in text and c["reason"].replace(">", "&gt;").replace("<", "&lt;") in text


def test_evaluate_prints_the_reports_figures(report, session, capsys):
    """evaluate and report compute mean, RMS, p95, max and ISO 9283 with one function."""
    capsys.readouterr()
    assert main(["evaluate", str(session / "val.csv"), "--model", str(session / "disc.json")]) == 0
    out = capsys.readouterr().out
    a = json.loads((session / "report.json").read_text())["held_out"]
    for k in ("rms", "mean", "p95", "max"):
        assert f"{k} {a['after'][k + '_mm']:.4f} mm" in out
    iso = a["iso9283_after"]
    assert f"AP max {iso['ap_mm']['max']:.4f} mm" in out and f"RP max {iso['rp_mm']['max']:.4f} mm" in out


def test_report_without_data_says_so(session):
    out = session / "fit_only.html"
    assert main(["report", str(session / "fit.json"), "--out", str(out)]) == 0
    text = out.read_text()
    assert "No verdict: no held-out measurements given" in text and "No discover history was given" in text


def test_report_shows_a_transfer_check_when_the_history_has_one(session):
    hist = json.loads((session / "hist.json").read_text())
    assert "transfer" not in hist
    out = session / "no_transfer.html"
    assert main(["report", str(session / "disc.json"), "--history", str(session / "hist.json"), "--out", str(out)]) == 0
    assert "Transfer check" not in out.read_text()
    # the record discover writes per round (torchcal.diagnosis.transfer.TransferCheck.choose)
    hist["history"][0]["transfer"] = {"current_mm": 0.4321, "kept": None,
                                      "tried": [{"effect": "gear_periodic:2", "after_mm": 0.9876, "refused": True,
                                                 "p_value": 1.0, "reason": "no gain (>=)"}]}
    (session / "hist_t.json").write_text(json.dumps(hist))
    out = session / "transfer.html"
    assert main(["report", str(session / "disc.json"), "--history", str(session / "hist_t.json"), "--out",
                 str(out)]) == 0
    text = out.read_text()
    assert "Transfer check" in text and "gear_periodic:2" in text and "0.4321" in text and "0.9876" in text
    assert "refused: helps within the session only (no gain (&gt;=))" in text
    # a step on several joints judged per joint part: each part's verdict and what landed
    hist["history"][0]["transfer"] = {
        "current_mm": 0.4321, "kept": "gear_periodic:2",
        "tried": [{"effect": "gear_periodic:1,2", "after_mm": 0.3012, "refused": False, "p_value": 1e-9,
                   "reason": "gain 30.3 %", "part_level": 0.025,
                   "parts": [{"joint": 1, "effect": "gear_periodic:1", "without_mm": 0.2101, "kept": False,
                              "p_value": 1.0, "reason": "no gain (>=)"},
                             {"joint": 2, "effect": "gear_periodic:2", "without_mm": 0.5012, "kept": True,
                              "p_value": 1e-12, "reason": "gain 39.9 %"}],
                   "landed": {"effect": "gear_periodic:2", "after_mm": 0.2034, "refused": False, "p_value": 1e-14,
                              "reason": "gain 52.9 %"}}]}
    (session / "hist_p.json").write_text(json.dumps(hist))
    out = session / "transfer_parts.html"
    assert main(["report", str(session / "disc.json"), "--history", str(session / "hist_p.json"), "--out",
                 str(out)]) == 0
    text = out.read_text()
    assert "joint 1: gear_periodic:1" in text and "0.2101" in text and "dropped (no gain (&gt;=)" in text
    assert "joint 2: gear_periodic:2" in text and "0.5012" in text and "0.2034" in text and "kept (gain 52.9 %)" in text


def test_report_names_the_joints_whose_part_holds_and_lists_the_fit_terms(session):
    """discover's split-half labels (torchcal.diagnosis.stability), per joint part of an
    effect on several joints, as its history JSON records them."""
    from torchcal.diagnosis.diagnose import Discovery
    from torchcal.diagnosis.stability import Stability

    hist = json.loads((session / "hist.json").read_text())
    spec = "joint_periodic:1@12+22,2@20+29"
    ok, bad = Stability(1e-9, "q1", 0.0123, 6), Stability(0.56, "q5", -0.0033, 6)
    st = {spec: Stability(0.56, "q5", -0.0033, 6, parts={1: ("joint_periodic:1@12+22", bad),
                                                          2: ("joint_periodic:2@20+29", ok)})}
    d = Discovery([], ["base_frame", spec], None, [], stability=st)
    hist.update(named=d.named, absorbing=d.absorbing,  # final_effects stay disc.json's: its own history
                stability={e: s.to_dict() for e, s in st.items()})
    (session / "hist_s.json").write_text(json.dumps(hist))
    out = session / "labels.html"
    assert main(["report", str(session / "disc.json"), "--history", str(session / "hist_s.json"), "--out",
                 str(out)]) == 0
    text = out.read_text()
    assert "Named as physics: base_frame, joint_periodic:2@20+29." in text
    assert ("In the model as fit terms only, not named: joint_periodic:1@12+22 (fitted on one side of the median "
            "of q5 it does not predict the other side better: gain -3.3 um, p 0.56).") in text
    assert ("; named as physics: base_frame, joint_periodic:2@20+29; fit terms only, not named: "
            "joint_periodic:1@12+22</td>") in text  # page 1's discovery row


@pytest.mark.parametrize("args,needle", [
    (["--tolerance-mm", "-1"], "--tolerance-mm"),
    (["--history", "{data}"], "history"),
    (["--model-is-data"], "MODEL.json"),
])
def test_bad_input_one_line_exit_2_nothing_written(session, capsys, args, needle):
    d = session
    out = d / "bad.html"
    model = str(d / "disc.json")
    if args == ["--model-is-data"]:
        args, model = [], str(d / "fit.json.missing")
        (d / "fit.json.missing").write_text('{"format": "torchcal-plan/1"}')
    args = [a.replace("{data}", str(d / "val.csv")) for a in args]
    try:
        code = main(["report", model, "--out", str(out)] + args)
    except SystemExit as ex:  # argparse
        code = ex.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err and "Traceback" not in err
    assert not out.exists()


def test_the_training_data_are_refused_as_held_out(session, capsys):
    """`report disc.json --data train.csv` (the file the model was fitted on) printed its
    figures as 'held-out rows' and a verdict on them; now one line naming the file and its
    SHA-256 match, exit 2, nothing written (a copy under another name too: the content counts)."""
    d = session
    (d / "train_copy.csv").write_bytes((d / "train.csv").read_bytes())
    for name in ("train.csv", "train_copy.csv"):
        out = d / "trained.html"
        assert main(["report", str(d / "disc.json"), "--data", str(d / name), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"torchcal report: error: {d / name}: the data the model was fitted on (SHA-256 as "
                              "its provenance records for ") and err.count("\n") == 1, err
        assert "give measurements the fit did not see" in err and not out.exists()


def test_the_history_of_another_model_is_refused(session, capsys):
    """`report fit.json --history hist.json` (the history of the discover that wrote
    disc.json, whose effects the fit lacks) was rendered in silence: the report told how
    effects that are not in the model were found. Now one line naming both files and both
    effect lists, exit 2, nothing written; the history of the model itself passes."""
    d = session
    final = json.loads((d / "hist.json").read_text())["final_effects"]
    assert final != ["base_frame"]  # discover added an effect the fit lacks
    out = d / "other.html"
    assert main(["report", str(d / "fit.json"), "--history", str(d / "hist.json"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err == (f"torchcal report: error: {d / 'hist.json'}: a discover history whose final effects "
                   f"[{', '.join(final)}] are not those of {d / 'fit.json'} [base_frame]: the history of another "
                   "model; give the history of the discover that wrote this model\n")
    assert not out.exists()
    assert main(["report", str(d / "disc.json"), "--history", str(d / "hist.json"), "--out", str(out)]) == 0


# --------------------------------------------------------------------------- in a browser
NO_NETWORK = ["--headless", "--no-sandbox", "--disable-gpu", "--proxy-server=127.0.0.1:9",
              "--host-resolver-rules=MAP * ~NOTFOUND", "--disable-background-networking", "--no-first-run"]

PROBE = """<script>
window.addEventListener('load', () => {
  const imgs = Array.from(document.images);
  const res = performance.getEntriesByType('resource').map(r => r.name);
  const out = document.createElement('pre');
  out.id = 'probe';
  out.style.display = 'none';  // in the DOM, not on the page: the screenshot and the PDF are the report's
  const loaded = imgs.filter(i => i.complete && i.naturalWidth > 0).length;
  out.textContent = JSON.stringify({imgs: imgs.length, loaded: loaded, requests: res,
                                    text: document.body.innerText.length});
  document.body.appendChild(out);
});
</script>"""


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (Debian: apt-get install -y chromium)")
def test_chromium_renders_every_figure_offline(report, tmp_path):
    """One headless Chromium run (each start is about 1 s of CPU over its processes) loads
    the report with a probe script, then dumps the DOM, takes a screenshot and prints a PDF."""
    probe = tmp_path / "probe.html"  # the report plus a probe script (the report itself has none)
    probe.write_text(report.read_text().replace("</body>", PROBE + "</body>"))
    shot, pdf = tmp_path / "shot.png", tmp_path / "report.pdf"
    dom = subprocess.run([CHROMIUM, *NO_NETWORK, "--virtual-time-budget=5000", "--dump-dom", f"--screenshot={shot}",
                          "--window-size=1000,1400", "--hide-scrollbars", f"--print-to-pdf={pdf}",
                          "--no-pdf-header-footer", probe.as_uri()], capture_output=True, text=True, timeout=120).stdout
    found = re.search(r'<pre id="probe"[^>]*>(.*?)</pre>', dom, re.S)
    assert found, "the probe did not run"
    got = json.loads(found.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    assert got["imgs"] >= 4 and got["loaded"] == got["imgs"]
    assert all(not r.startswith("http") for r in got["requests"]), got["requests"]
    assert got["text"] > 2000
    from matplotlib.image import imread

    px = imread(shot)
    assert px.shape[0] >= 1000 and px[..., :3].std() > 0.05, "a blank page"
    pages = pdf.read_bytes().count(b"/Type /Page") - pdf.read_bytes().count(b"/Type /Pages")
    assert pages >= 6  # the summary, then a page break before each section


# --------------------------------------------------------------------------- the paper's pipeline
def test_report_on_a_zone_calibration(tmp_path):
    """`calibrate --partition` (interval model per zone) on a robot with compliance: the
    report predicts each held-out row with its zone's parameters and shows the paper's
    Table 5 with R_set before and after."""
    d = tmp_path
    assert main(["sweep", "--robot", "kr1000titan", "--n", "80", "--samples", "50", "--allowed", "1.0", "--seed", "3",
                 "--no-progress", "--out", str(d / "sweep.csv")]) == 0
    assert main(["partition", str(d / "sweep.csv"), "--levels", "2", "--zones", "2,1", "--out",
                 str(d / "part.json")]) == 0
    sim = ["simulate", "--robot", "kr1000titan", "--effects", "joint_compliance:2", "--repeats", "3",
           "--noise", "0.02", "--seed", "4"]
    assert main(sim + ["--n", "80", "--out", str(d / "train.csv")]) == 0
    assert main(sim + ["--pose-seed", "5", "--n", "20", "--out", str(d / "val.csv")]) == 0
    assert main(["calibrate", str(d / "train.csv"), "--robot", "kr1000titan", "--partition", str(d / "part.json"),
                 "--out", str(d / "zones.json")]) == 0
    assert main(["report", str(d / "zones.json"), "--data", str(d / "val.csv"), "--tolerance-mm", "0.5",
                 "--out", str(d / "r.html"), "--json", str(d / "r.json")]) == 0
    text = (d / "r.html").read_text()
    js = json.loads((d / "r.json").read_text())["held_out"]
    table = js["zone_table"]
    assert len(table) == 20 and {r["zone"] for r in table} <= {1, 2, 3}
    assert "Table 5" in text and "Interval parameters per zone" in text and not re.search(r"https?://", text)
    for r in table:
        for k in ("before", "after"):
            assert all(lo <= hi for lo, hi in zip(r[k]["lower"], r[k]["upper"]))
            assert all(0.0 <= v <= 1.0 for v in r[k]["r_set"])
    # the calibrated zones beat the nominal robot on poses they never saw, and R_set rises
    assert js["after"]["rms_mm"] < js["before"]["rms_mm"]
    mean = lambda k: sum(r[k]["r_set"][3] for r in table) / len(table)  # noqa: E731
    assert mean("after") >= mean("before")


@pytest.fixture(scope="module")
def nan_model(tmp_path_factory):
    """A fit of a simulated ur5e session (s.csv) and its MODEL.json with da2 set to NaN (nan.json)."""
    d = tmp_path_factory.mktemp("nan")
    assert main(["simulate", "--robot", "ur5e", "--n", "30", "--seed", "4", "--out", str(d / "s.csv")]) == 0
    assert main(["fit", str(d / "s.csv"), "--robot", "ur5e", "--out", str(d / "m.json")]) == 0
    obj = json.loads((d / "m.json").read_text())
    next(p for p in obj["parameters"] if p["name"] == "da2")["value"] = float("nan")
    (d / "nan.json").write_text(json.dumps(obj))
    return d


@pytest.mark.parametrize("data", [False, True])
def test_a_model_with_nan_is_refused_with_or_without_data(nan_model, tmp_path, capsys, data):
    """A parameter value NaN in MODEL.json (a hand edit, a broken copy): every other
    command refuses the file in one line; without --data the report wrote a page that
    printed 'nan' for the parameter."""
    capsys.readouterr()
    out = tmp_path / "r.html"
    code = main(["report", str(nan_model / "nan.json"), "--out", str(out)]
                + (["--data", str(nan_model / "s.csv")] if data else []))
    err = capsys.readouterr().err.strip()
    assert not out.exists() and code == 2
    assert len(err.splitlines()) == 1 and "da2" in err and "finite" in err


def test_base_frame_parameters_are_labelled_a_rotation_vector(tmp_path, capsys):
    """base_rx..base_rz are the components of a rotation vector (deg), the page's
    provenance gives the same rotation as fixed-XYZ angles: two sets of 'rx, ry, rz' with
    other values. Read as XYZ angles the parameters turn this frame by 2.97 deg (on the UR10
    fit of examples/ur10 by 0.029 deg, 0.77 mm at 1.5 m): fit and the report say which is which."""
    import csv

    import numpy as np
    from scipy.spatial.transform import Rotation

    assert main(["simulate", "--robot", "ur5e", "--n", "40", "--seed", "6", "--out", str(tmp_path / "s.csv")]) == 0
    W = Rotation.from_euler("xyz", [10.0, -5.0, 30.0], degrees=True)  # a tracker turned and tilted
    rows = list(csv.DictReader(open(tmp_path / "s.csv")))
    for r in rows:
        p = W.apply([float(r[k]) for k in "xyz"]) + [2000.0, -1500.0, -300.0]
        r.update(zip("xyz", map(repr, p.tolist())))
    with open(tmp_path / "w.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    capsys.readouterr()
    assert main(["fit", str(tmp_path / "w.csv"), "--robot", "ur5e", "--effects", "base_frame",
                 "--out", str(tmp_path / "m.json")]) == 0
    fit_out = capsys.readouterr().out
    obj = json.loads((tmp_path / "m.json").read_text())
    v = {p["name"]: p["value"] for p in obj["parameters"]}
    vec = np.array([v["base_rx"], v["base_ry"], v["base_rz"]])  # deg, as the file holds them
    xyz = np.array(obj["base_frame"]["rotation_fixed_xyz_deg"])
    assert (Rotation.from_rotvec(np.radians(vec)).inv() * W).magnitude() < 1e-3  # a rotation vector of W
    assert np.abs(vec - xyz).max() > 1.0  # not the XYZ angles printed beside them (2.3 deg apart here)
    assert main(["report", str(tmp_path / "m.json"), "--out", str(tmp_path / "r.html")]) == 0
    text = (tmp_path / "r.html").read_text()
    assert "base_rx..base_rz: the rotation vector" in text
    assert "base_rx..base_rz below: the rotation vector" in fit_out


def test_before_of_a_tool_offset_model_fits_the_tool_on_the_nominal_robot(tmp_path):
    """Two reflectors 100 mm from the flange, data in the robot's base frame (a plain-numpy
    ur5e with MD-H errors), a model with tool_offset and no base_frame: "before" took the
    nominal robot with its nominal tool, so the reflectors' own 100 mm made the nominal
    error (98.6 mm rms, -99.98 %). Now it is the nominal robot with the tool offsets fitted
    on these rows, as a base frame is for tracker data: here a linear least-squares in numpy
    of each reflector's offset on the nominal flange frames."""
    import numpy as np
    from npsim import numpy_frames, reflectors_session

    import torchcal

    rob = torchcal.robot("ur5e")
    pts = {1: [30.0, 0.0, 100.0], 2: [-20.0, 40.0, 80.0]}
    reflectors_session(tmp_path / "s.csv", rob, 40, pts)
    _, q, meas = reflectors_session(tmp_path / "v.csv", rob, 40, pts, seed=5)  # not the training file
    assert main(["fit", str(tmp_path / "s.csv"), "--robot", "ur5e", "--effects", "tool_offset",
                 "--out", str(tmp_path / "m.json")]) == 0
    assert main(["report", str(tmp_path / "m.json"), "--data", str(tmp_path / "v.csv"), "--out",
                 str(tmp_path / "r.html"), "--json", str(tmp_path / "r.json")]) == 0
    before = json.loads((tmp_path / "r.json").read_text())["held_out"]["before"]["rms_mm"]
    F = [numpy_frames(rob, qq, np.zeros((6, 5)))[-1] for qq in q]  # nominal flange frames
    res = []
    for pid in pts:
        A = np.concatenate([f[:3, :3] for f in F])  # (3N, 3): position = R p + o
        b = np.concatenate([x - f[:3, 3] for f, x in zip(F, meas[pid])])
        p = np.linalg.lstsq(A, b, rcond=None)[0]
        res.append((b - A @ p).reshape(-1, 3))
    expected = float(np.sqrt((np.linalg.norm(np.concatenate(res), axis=1) ** 2).mean()))
    assert before == pytest.approx(expected, rel=1e-4), (before, expected)


def test_the_report_carries_the_warning_of_held_out_rows_outside_the_fitted_temperatures(tmp_path, capsys):
    """A thermal model (plain-numpy link growth, tests/npsim.py) fitted at 18-26 degC: held-out
    rows at 34-40 degC get evaluate's extrapolation warning on stderr, and the report handed
    over says it too (HTML first page, JSON); held-out rows inside the range say nothing."""
    import torchcal
    from torchcal.io.measurement_csv import write_measurements
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    from npsim import thermal_session

    rob = torchcal.robot("ur5e")

    def session(path, n, seed, hot=0):
        q = random_poses(rob, n, seed)
        temp = np.random.default_rng(seed + 100).uniform(18.0, 26.0, n)
        temp[:hot] = np.linspace(34.0, 40.0, hot)
        xyz = thermal_session(rob, q.numpy(), temp, seed=7)
        write_measurements(path, Measurements(torch.arange(n), q, torch.from_numpy(xyz),
                                              temp_c=torch.from_numpy(temp)), robot=rob)

    session(tmp_path / "train.csv", 80, 1)
    session(tmp_path / "cool.csv", 30, 2)
    session(tmp_path / "hot.csv", 30, 3, hot=7)
    assert main(["fit", str(tmp_path / "train.csv"), "--robot", "ur5e", "--effects", "thermal_expansion",
                 "--out", str(tmp_path / "m.json")]) == 0
    lo, hi = json.loads((tmp_path / "m.json").read_text())["calibrated_conditions"]["temp_c"]
    for name, expected in (("cool", None), ("hot", f"temperature of 7 of 30 rows outside the fitted {lo:.4g} .. "
                                                    f"{hi:.4g} degC (farthest 40 degC)")):
        capsys.readouterr()
        assert main(["report", str(tmp_path / "m.json"), "--data", str(tmp_path / f"{name}.csv"),
                     "--out", str(tmp_path / f"{name}.html"), "--json", str(tmp_path / f"{name}.json")]) == 0
        err = capsys.readouterr().err
        text = (tmp_path / f"{name}.html").read_text()
        said = json.loads((tmp_path / f"{name}.json").read_text())["held_out"]["data_warnings"]
        if expected is None:
            assert said == [] and "Warning:" not in text and "degC" not in err
        else:
            assert len(said) == 1 and expected in said[0] and expected in text and err.count(expected) == 1


def test_the_report_says_when_held_out_rows_without_a_payload_meet_a_model_fitted_on_loads(tmp_path, capsys):
    """A joint-compliance model fitted on 0..5 kg (plain-numpy gravity sag, tests/npsim.py):
    held-out rows without their payload column are evaluated unloaded; the report says so."""
    import torchcal
    from torchcal.io.measurement_csv import write_measurements
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    from npsim import physics_session

    rob = torchcal.robot("ur5e")
    q = random_poses(rob, 100, 4)
    xyz, load = physics_session(rob, q.numpy(), seed=4, hidden=["joint_compliance:2,3"])
    xyz, load = torch.from_numpy(xyz), torch.from_numpy(load)
    write_measurements(tmp_path / "train.csv", Measurements(torch.arange(70), q[:70], xyz[:70], payload_kg=load[:70]))
    write_measurements(tmp_path / "val.csv", Measurements(torch.arange(70, 100), q[70:], xyz[70:]))
    assert main(["fit", str(tmp_path / "train.csv"), "--robot", "ur5e", "--effects", "joint_compliance:2,3",
                 "--out", str(tmp_path / "m.json")]) == 0
    assert main(["report", str(tmp_path / "m.json"), "--data", str(tmp_path / "val.csv"),
                 "--out", str(tmp_path / "r.html"), "--json", str(tmp_path / "r.json")]) == 0
    said = json.loads((tmp_path / "r.json").read_text())["held_out"]["data_warnings"]
    assert len(said) == 1 and "no payload_kg column: evaluated at 0 kg" in said[0]
    assert html.escape(said[0]) in (tmp_path / "r.html").read_text() and said[0] in capsys.readouterr().err
