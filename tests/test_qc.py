"""``torchfill qc``: a verdict per gap (ok / check / reject) with its reasons and thresholds in the
file's units, frame numbers as the file counts them, JSON for pipelines, an HTML report a browser
renders, and 2-D keypoint fills."""
from __future__ import annotations

import json
import shutil
import subprocess
import warnings

import numpy as np
import pytest

import torchfill
from torchfill import qc
from torchfill.cli import main

from benchmarks.suites.qc import PLAUSIBLE_FILES


def body(T: int = 300, seed: int = 0) -> np.ndarray:
    """Six markers of one rigid body (a 200 mm box) turning and moving, in mm: (T, 6, 3)."""
    rng = np.random.default_rng(seed)
    local = rng.uniform(-100, 100, size=(6, 3))
    t = np.arange(T) / 100.0
    a = 0.8 * np.sin(2 * np.pi * 0.5 * t)
    R = np.zeros((T, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = (np.cos(a), -np.sin(a), np.sin(a),
                                                                  np.cos(a), 1.0)
    centre = np.stack([400 * np.sin(2 * np.pi * 0.3 * t), 200 * t, 900 + 0 * t], axis=1)
    return np.einsum("tij,kj->tki", R, local) + centre[:, None]


def rows_by_start(rows):
    return {(r["marker"], r["start"]): r for r in rows}


def test_each_test_gives_its_verdict_and_reason_with_the_threshold():
    X = body()
    gappy = X.copy()
    gappy[100:140, 1] = np.nan            # filled 600 mm off: a step above the cap
    gappy[200:220, 2] = np.nan            # filled exactly
    gappy[50:60, 3] = np.nan              # filled off its rigid partners by 40 mm
    gappy[270:, 4] = np.nan               # trial end, filled exactly
    gappy[:40, 5] = np.nan                # trial start, left unfilled
    filled = X.copy()
    filled[120:140, 1] += 600.0
    filled[50:60, 3] += 40.0 * np.linspace(0, 1, 10)[:, None] * np.array([1.0, 0.0, 0.0])
    filled[:40, 5] = np.nan
    rows = rows_by_start(qc.gap_table(gappy, filled, 100.0, [f"M{j}" for j in range(6)],
                                      units="mm"))
    jump, exact, bent, end, empty = (rows[("M1", 100)], rows[("M2", 200)], rows[("M3", 50)],
                                     rows[("M4", 270)], rows[("M5", 0)])
    assert jump["verdict"] == "reject" and any("above the cap" in r for r in jump["reasons"])
    assert exact["verdict"] == "ok" and exact["reasons"] == []
    assert bent["verdict"] in ("check", "reject")
    assert any("spread" in r and "M" in r for r in bent["reasons"])
    assert end["kind"] == "end" and end["verdict"] == "ok"
    assert empty["verdict"] == "reject" and empty["reasons"] == ["left unfilled"]
    text = qc.format_table(list(rows.values()))
    cap = jump["thresholds"].step_cap
    assert f"{cap:.4g} mm" in text and "thresholds (mm)" in text


def test_a_step_exactly_at_the_cap_is_flagged():
    """The constraints shorten a fill's steps to just below the cap: a gap that needed it ends at
    the cap, and that must not pass as ok -- an interior gap at the step cap, a trial-end gap at
    the lower cap of a fill held at one edge only; float32 rounding above a cap is not "above"."""
    X = body()
    gappy = X.copy()
    gappy[280:, 0] = np.nan
    gappy[100:120, 1] = np.nan
    observed = np.isfinite(gappy).all(axis=2)
    from torchfill.metrics import step_limit
    from torchfill.constraints import END_STEP_FACTOR, STEP_FACTOR, STEP_PERCENTILE
    cap = step_limit(X, observed, q=STEP_PERCENTILE, factor=STEP_FACTOR)
    end_cap = cap * END_STEP_FACTOR / STEP_FACTOR
    filled = X.copy()
    filled[280, 0] = X[279, 0] + 0.999 * end_cap * np.array([1.0, 0.0, 0.0])  # as _limit_steps
    filled[281:, 0] = filled[280, 0] + (X[281:, 0] - X[280, 0])
    line = X[99, 1] + np.linspace(0, 1, 22)[:, None] * (X[120, 1] - X[99, 1])   # frames 99-120
    filled[100:120, 1] = line[1:-1]
    d = line[1] - line[0]
    filled[110, 1] = line[10] + 0.999 * cap * d / np.linalg.norm(d)    # one step of 0.999 cap
    rows = rows_by_start(qc.gap_table(gappy, filled, 100.0, units="mm"))
    end, inner = rows[("0", 280)], rows[("1", 100)]
    assert end["max_step"] < end_cap and end["verdict"] == "check"
    assert any("at the trial-end cap" in r for r in end["reasons"])
    assert end["max_step"] < inner["max_step"] < cap * (1 + qc.STEP_ROUNDING)
    assert inner["verdict"] != "ok" and any("at the cap" in r for r in inner["reasons"])
    filled32 = filled.astype(np.float32).astype(np.float64)          # as a C3D file keeps it
    inner32 = rows_by_start(qc.gap_table(gappy, filled32, 100.0, units="mm"))[("1", 100)]
    assert not any("above the cap" in r for r in inner32["reasons"])


def loose(T: int = 300, J: int = 6, seed: int = 0) -> np.ndarray:
    """Markers moving independently (no rigid partners, no segment-mates), in mm: (T, J, 3)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None] / 100.0
    f, p = rng.uniform(0.2, 1.0, size=(1, J, 3)), rng.uniform(0, 6.3, size=(1, J, 3))
    return 300 * np.sin(2 * np.pi * f * t + p) + rng.uniform(-500, 500, size=(1, J, 3))


def test_the_error_estimate_decides_between_ok_check_and_reject():
    X = loose()
    gappy = X.copy()
    for j in range(6):
        gappy[40 * j + 20:40 * j + 40, j] = np.nan
    std = np.full(X.shape[:2], np.nan)
    per_coord = [1.0, 1.0, 1.0, 1.0, 15.0, 40.0]      # mm; 3-D RMS = sqrt(3) x
    for j, s in enumerate(per_coord):
        std[40 * j + 20:40 * j + 40, j] = s
    rows = qc.gap_table(gappy, X, 100.0, std=std, units="mm", support=np.zeros(X.shape[:2], bool))
    verdicts = [r["verdict"] for r in sorted(rows, key=lambda r: r["j"])]
    assert verdicts == ["ok", "ok", "ok", "ok", "check", "reject"]
    assert rows[0]["est_rmse"] == pytest.approx(np.sqrt(3.0))
    # the same data in metres: the same verdicts, thresholds printed in m
    rows_m = qc.gap_table(gappy / 1000, X / 1000, 100.0, std=std / 1000, units="m",
                          support=np.zeros(X.shape[:2], bool))
    assert [r["verdict"] for r in sorted(rows_m, key=lambda r: r["j"])] == verdicts
    assert "> 0.008 m" in qc.format_table(rows_m)


def test_frame_numbers_and_json_follow_the_file(tmp_path):
    X = body(T=120)
    gappy = X.copy()
    gappy[30:45, 2] = np.nan
    rows = qc.gap_table(gappy, X, 100.0, ["A", "B", "C", "D", "E", "F"], first_frame=290)
    (row,) = qc.to_json(rows)
    assert (row["marker"], row["first_frame"], row["last_frame"]) == ("C", 320, 334)
    assert row["verdict"] in qc.VERDICTS and isinstance(row["reasons"], list)
    assert row["est_rmse"] is None and row["segment"] is None
    json.dumps(qc.to_json(rows))                     # plain JSON types only


def test_qc_cli_on_a_c3d_numbered_from_290_and_on_its_trc(recording, tmp_path, capsys):
    """walking_hybrid_1_1 starts at C3D frame 290; the TRC written from it starts at Frame# 290:
    info, the text table, the JSON and the report number frames that way."""
    src = recording("c3dorg_s26_walking_hybrid_1_1.c3d")
    seq = torchfill.read(src)
    trc = tmp_path / "wh.trc"
    torchfill.write(seq, trc)
    runs = torchfill.metrics.gap_runs(seq.mask)
    expect = sorted((seq.labels[j], 290 + a, 290 + b - 1) for j, a, b in runs)
    for path in (src, trc):
        filled = tmp_path / f"f{path.suffix}"
        out_json = tmp_path / f"{path.suffix[1:]}.json"
        report = tmp_path / f"{path.suffix[1:]}.html"
        assert main(["fill", str(path), "-o", str(filled), "-m", "pchip", "-q"]) == 0
        capsys.readouterr()
        assert main(["qc", str(path), str(filled), "-o", str(report), "--json", str(out_json)]) == 0
        out = capsys.readouterr().out
        got = json.loads(out_json.read_text())
        assert sorted((r["marker"], r["first_frame"], r["last_frame"]) for r in got) == expect
        assert "290-303" in out                     # R_ASIS's first gap, the file's numbering
        page = report.read_text()
        assert "numbered 290-961" in page and ">290<" in page
        assert main(["info", str(path)]) == 0
        info = capsys.readouterr().out
        assert "numbered 290-961" in info and "290-303" in info


def test_info_numbers_frames_from_the_c3d_first_frame(recording, capsys):
    assert main(["info", str(recording("cmu_02_01.c3d"))]) == 0
    assert "numbered 50-392" in capsys.readouterr().out


def test_std_csv_numbers_frames_as_the_file_and_qc_reads_it_back(recording, tmp_path, capsys):
    src = recording("c3dorg_s26_walking_hybrid_1_1.c3d")
    filled, std = tmp_path / "f.c3d", tmp_path / "std.csv"
    assert main(["fill", str(src), "-o", str(filled), "-m", "pchip", "--std", str(std), "-q"]) == 0
    assert std.read_text().splitlines()[1].startswith("290,")
    capsys.readouterr()
    assert main(["qc", str(src), str(filled), "--std", str(std), "--json", "-",
                 "-o", str(tmp_path / "r.html")]) == 0
    got = json.loads(capsys.readouterr().out)
    assert all(r["est_rmse"] is not None for r in got if r["verdict"] != "reject"
               or r["reasons"] != ["left unfilled"])


def test_verdict_tracks_the_true_error_on_the_tennis_file(recording):
    """ktk_tennis_serve_nan against its clean twin: the default fill with its own error estimate;
    no gap under 5 mm true RMS error is flagged, and the gap the estimate ranks worst is."""
    gappy = torchfill.read(recording("ktk_tennis_serve_nan.c3d"))
    truth = torchfill.read(recording("ktk_tennis_serve.c3d")).points
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out, std = torchfill.fill(gappy, return_std=True)
    rows = qc.gap_table(gappy.points, out.points, gappy.rate, gappy.labels, std, units="m")
    true = []
    for r in rows:
        e = np.linalg.norm(out.points[r["start"]:r["stop"], r["j"]]
                           - truth[r["start"]:r["stop"], r["j"]], axis=1)
        true.append(1000 * np.sqrt(np.nanmean(e ** 2)))
    small = [r["verdict"] for r, t in zip(rows, true) if t < 5.0]
    assert small and sum(v != "ok" for v in small) <= 0.15 * len(small)
    worst = max(rows, key=lambda r: r["est_rmse"])
    assert worst["verdict"] != "ok"


def test_labels_with_dollars_reach_the_report_literally(tmp_path):
    """Two ``$`` in a label were parsed as mathtext by matplotlib and crashed the report."""
    X = body()
    gappy = X.copy()
    gappy[100:140, 1] = np.nan
    filled = X.copy()
    filled[120:140, 1] += 600.0                   # reject: gets a figure
    gappy[10:20, 4] = np.nan                      # ok: in the table and the overview
    names = ["a$b$c", "$\\frac{1}{0$", "_hidden", "x^2_{y}", "<i>&x", "ok"]
    rows = qc.gap_table(gappy, filled, 100.0, names)
    page = qc.html_report(gappy, filled, rows, title="t$1$", rate=100.0, units="mm", names=names)
    assert page.count("<figure") == 1 and "<svg" in page
    assert "$\\frac{1}{0$" in page or "$\\frac{1}{0$".replace("<", "&lt;") in page
    assert "<i>&x" not in page and "&lt;i&gt;&amp;x" in page


def test_report_is_self_contained_and_renders_in_a_headless_browser(recording, tmp_path, capsys):
    src = recording("c3dorg_s02_pc_real.c3d")
    filled = tmp_path / "pc_filled.c3d"
    report = tmp_path / "pc.html"
    assert main(["fill", str(src), "-o", str(filled), "-m", "pchip", "-q"]) == 0
    assert main(["qc", str(src), str(filled), "-o", str(report)]) == 0
    page = report.read_text()
    seq = torchfill.read(src)
    n_gaps = len([1 for j, a, b in torchfill.metrics.gap_runs(seq.mask)
                  if not seq.mask[:, j].all()])
    assert page.startswith("<!doctype html>") and "<svg" in page and "class='sortable'" in page
    assert page.count("<tr class=") == n_gaps
    for remote in ("http://", "https://", "src='//", 'src="//'):
        assert remote not in page.replace("http://www.w3.org/2000/svg", "")
    n_bad = sum(1 for line in page.splitlines() if line.startswith("<figure"))
    assert n_bad == min(sum(1 for r in page.split("<tr class='")[1:]
                            if not r.startswith("ok")), 200)
    browser = shutil.which("chromium") or shutil.which("chromium-headless-shell")
    if browser is None:
        pytest.skip("no headless chromium to render the report")
    png = tmp_path / "qc.png"
    subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu",
                    f"--screenshot={png}", "--window-size=1200,1600", report.as_uri()],
                   capture_output=True, timeout=120, check=False)
    assert png.is_file() and png.stat().st_size > 20_000     # a page with plots, not blank


def test_qc_rejects_mismatched_files(recording, tmp_path, capsys):
    a = recording("c3dorg_s02_pc_real.c3d")
    b = recording("mogapfill_gait-raw.csv")
    assert main(["qc", str(a), str(b), "-o", str(tmp_path / "x.html")]) == 2
    assert capsys.readouterr().err.startswith("torchfill: error: ")


def test_qc_and_fill_report_on_openpose_folders_speak_pixels(tmp_path, capsys):
    """A fill of 2-D keypoints is judged (not called unfilled), in px; ``fill DIR --report``
    and ``--report-json`` work."""
    from torchfill.sequence import MarkerSequence

    X = body()[:, :, :2] + 500.0                   # keypoints in pixels
    mask = np.zeros(X.shape[:2], dtype=bool)
    mask[100:130, 1] = mask[200:220, 3] = mask[:5, 4] = True
    seq = MarkerSequence(points=np.where(mask[..., None], np.nan, X), labels=[f"K{j}" for j in
                         range(6)], rate=30.0, units="px")
    src, out = tmp_path / "in", tmp_path / "out"
    torchfill.write(seq, src)
    report, rj = tmp_path / "r.html", tmp_path / "r.json"
    assert main(["fill", str(src), "-o", str(out), "-m", "pchip", "--report", str(report),
                 "--report-json", str(rj), "-q"]) == 0
    got = json.loads(rj.read_text())
    assert len(got) == 3 and all(r["reasons"] != ["left unfilled"] for r in got)
    assert report.read_text().count("<tr class=") == 3
    capsys.readouterr()
    assert main(["qc", str(src), str(out), "-o", str(tmp_path / "q.html")]) == 0
    text = capsys.readouterr().out
    assert "thresholds (px)" in text and "rigid" not in text
    # the interior gaps pass; PCHIP holds K4 still over the trial start while it moves ~10 px a
    # frame, and its one step back onto the track ends at the trial-end cap
    assert "3 gaps: 2 ok, 1 check" in text
    assert any(line.startswith("K4") and "at the trial-end cap" in line
               for line in text.splitlines())


def test_a_short_gap_filled_off_its_interpolation_is_flagged_whatever_the_estimate():
    """An interior gap of 0.05 s: the interpolation across it errs by far less than a mm; a fill
    20 mm off it is ``check`` even when its own estimate says 0.1 mm."""
    X = loose()
    gappy = X.copy()
    gappy[100:105, 2] = gappy[200:205, 3] = np.nan
    filled = X.copy()
    filled[100:105, 2] += np.array([20.0, 0.0, 0.0])
    std = np.where(np.isnan(gappy).any(axis=2), 0.1, np.nan)
    rows = rows_by_start(qc.gap_table(gappy, filled, 100.0, std=std, units="mm"))
    off, fine = rows[("2", 100)], rows[("3", 200)]
    assert off["verdict"] == "check" and any("interpolation" in r for r in off["reasons"])
    assert off["disagree"] == pytest.approx(20.0, rel=0.05)
    assert fine["verdict"] == "ok" and fine["disagree"] < 1.0


def test_a_short_gap_on_its_interpolation_is_not_flagged_on_a_large_estimate_alone():
    """Two independent fills agree: a 0.05 s interior gap filled within ``AGREE_MM`` of the
    interpolation across it stays ``ok`` although its estimate says 20 mm (the reason says so);
    a 0.5 s gap with the same estimate, or a short one filled 20 mm off, is flagged."""
    X = loose()
    gappy = X.copy()
    gappy[100:105, 2] = gappy[100:150, 4] = gappy[200:205, 3] = np.nan
    filled = X.copy()
    filled[200:205, 3] += np.array([20.0, 0.0, 0.0])
    std = np.where(np.isnan(gappy).any(axis=2), 20.0 / np.sqrt(3), np.nan)   # est_rmse 20 mm
    for j in (0, 1, 5):                   # the recording's other gaps: estimated 0.5 mm
        gappy[20:25, j] = gappy[250:255, j] = np.nan
        std[20:25, j] = std[250:255, j] = 0.5 / np.sqrt(3)
    rows = rows_by_start(qc.gap_table(gappy, filled, 100.0, std=std, units="mm"))
    short, long_, off = rows[("2", 100)], rows[("4", 100)], rows[("3", 200)]
    assert short["est_rmse"] == pytest.approx(20.0) and short["disagree"] < qc.AGREE_MM
    assert short["verdict"] == "ok" and any("within" in r for r in short["reasons"])
    assert long_["verdict"] == "check" and np.isnan(long_["disagree"])
    assert off["verdict"] == "check"
    assert any("estimated error" in r for r in off["reasons"])


def test_a_short_gap_filled_by_the_interpolation_itself_is_judged_on_its_estimate():
    """A 0.05 s interior gap whose fill is the interpolation across it (what the default's
    finishing step leaves where its fill departed from it) has no second fill to agree with:
    an estimate of 20 mm flags it, where the same estimate on a fill within ``AGREE_MM`` (but
    not on the interpolation) does not."""
    from torchfill.qc.finish import short_gap_fallback

    X = loose()
    gappy = X.copy()
    gappy[100:105, 2] = gappy[200:205, 3] = np.nan
    off = X.copy()
    off[100:105, 2] += np.array([20.0, 0.0, 0.0])
    filled, changed, _ = short_gap_fallback(gappy, off, 100.0)
    assert changed == [(2, 100, 105)]
    std = np.where(np.isnan(gappy).any(axis=2), 20.0 / np.sqrt(3), np.nan)
    for j in (0, 1, 5):                   # the recording's other gaps: estimated 0.5 mm
        gappy[20:25, j] = gappy[250:255, j] = np.nan
        std[20:25, j] = std[250:255, j] = 0.5 / np.sqrt(3)
    rows = rows_by_start(qc.gap_table(gappy, filled, 100.0, std=std, units="mm"))
    same, near = rows[("2", 100)], rows[("3", 200)]
    assert same["disagree"] <= qc.SAME_MM < near["disagree"] <= qc.AGREE_MM
    assert same["verdict"] == "check" and any("estimated error" in r for r in same["reasons"])
    assert near["verdict"] == "ok"


def test_untested_names_the_filled_samples_of_markers_without_an_observed_step():
    """A marker seen only in isolated frames is untested where the fill has an estimate; one seen
    in two consecutive frames, one never seen, and samples without an estimate are not."""
    missing = np.ones((8, 4), dtype=bool)
    missing[[0, 2, 5], 0] = False            # isolated frames only
    missing[[3, 4], 1] = False               # one observed step
    missing[:, 3] = False                    # always seen
    std = np.ones(missing.shape)
    std[6, 0] = np.nan                       # no estimate there
    got = qc.untested(missing, std)
    expected = missing.copy()
    expected[:, 1:] = False
    expected[6, 0] = False
    assert np.array_equal(got, expected) and int(got.sum()) == 4


def test_alone_names_uncertain_fills_of_markers_whose_segment_mates_are_never_observed():
    """A filled sample is alone where no other marker of any of the marker's segments is observed
    in any frame and its 3-D estimate is above the check level (in the data's units); a mate
    observed once in one of its segments, an estimate at or below the level, a marker in no
    segment, a sample left NaN or an observed one is not."""
    T = 6
    missing = np.zeros((T, 6), dtype=bool)
    missing[:, 1] = missing[:, 2] = True      # never observed
    missing[2:, 0] = True                     # 0: mates 1 (a) and 2 (b) never observed
    missing[1:, 3] = True                     # 3: its mate 4 (c) is
    missing[:, 4] = False
    missing[3:, 5] = True                     # 5: in no segment
    missing[0, 4] = True                      # 4: observed but in frame 0
    present = ~missing
    present[2:, 0] = present[1:, 3] = present[3:, 5] = True      # filled
    present[5, 0] = False                     # left NaN by another rule
    std = np.full((T, 6), 10.0)               # 3-D estimate 17 mm
    std[3, 0] = 4.0                           # 6.9 mm: at most the check level
    segments = {"a": [0, 1], "b": [0, 2], "c": [3, 4, 1], "d": [5]}
    got = qc.alone(present, missing, std, segments)
    expected = np.zeros((T, 6), dtype=bool)
    expected[[2, 4], 0] = True
    assert np.array_equal(got, expected)
    assert np.array_equal(qc.alone(present, missing, std * 1e-3, segments, units="m"), expected)
    expected[3, 0] = True                     # 6.9 m is above 8 mm
    assert np.array_equal(qc.alone(present, missing, std, segments, units="m"), expected)


def test_drop_rejected_leaves_only_the_rejected_fills_nan():
    X = body()
    gappy = X.copy()
    gappy[100:140, 1] = np.nan            # filled 600 mm off: reject
    gappy[200:220, 2] = np.nan            # filled exactly: ok
    gappy[:40, 5] = np.nan                # left unfilled: reject, nothing to drop
    filled = X.copy()
    filled[120:140, 1] += 600.0
    filled[:40, 5] = np.nan
    std = np.where(np.isnan(gappy).any(axis=2) & np.isfinite(filled).all(axis=2), 1.0, np.nan)
    rows = qc.gap_table(gappy, filled, 100.0, [f"M{j}" for j in range(6)], std, units="mm")
    F, S, dropped = qc.drop_rejected(filled, rows, std)
    assert [(r["marker"], r["start"]) for r in dropped] == [("M1", 100)]
    assert np.isnan(F[100:140, 1]).all() and np.isnan(S[100:140, 1]).all()
    keep = np.ones(X.shape[:2], dtype=bool)
    keep[100:140, 1] = False
    assert np.array_equal(F[keep], filled[keep], equal_nan=True)         # the rest bit for bit
    assert np.array_equal(S[keep], std[keep], equal_nan=True)


def test_fill_rejected_drop_leaves_the_rejected_gaps_unfilled_and_says_so(tmp_path, capsys):
    X = body()
    gappy = X.copy()
    gappy[100:160, 1] = np.nan            # a rotating rigid body: a straight line is far off
    gappy[200:203, 2] = np.nan
    src = tmp_path / "a.npz"
    np.savez(src, points=gappy, labels=np.array([f"M{j}" for j in range(6)]), rate=100.0)
    args = ["-m", "linear", "--no-constraints", "--std", str(tmp_path / "s.csv"), "-q"]
    assert main(["fill", str(src), "-o", str(tmp_path / "keep.npz"), *args]) == 0
    assert main(["qc", str(src), str(tmp_path / "keep.npz"), "--std", str(tmp_path / "s.csv"),
                 "-m", "linear", "--json", "-", "-o", str(tmp_path / "k.html"), "-q"]) == 0
    kept = json.loads(capsys.readouterr().out)
    rejected = [r for r in kept if r["verdict"] == "reject"]
    assert [(r["marker"], r["first_frame"]) for r in rejected] == [("M1", 100)]
    assert main(["fill", str(src), "-o", str(tmp_path / "drop.npz"), "--rejected", "drop",
                 *args[:-3], "-q"]) == 0
    err = capsys.readouterr().err
    assert "60 filled sample(s) of 1 gap(s) the qc verdict rejects left NaN (M1;" in err
    keep, drop = (torchfill.read(tmp_path / n).points for n in ("keep.npz", "drop.npz"))
    assert np.isnan(drop[100:160, 1]).all()
    rest = np.ones(X.shape[:2], dtype=bool)
    rest[100:160, 1] = False
    assert np.array_equal(drop[rest], keep[rest])


def test_qc_finds_the_estimate_the_default_fill_wrote_beside_its_output(walk, tmp_path, capsys):
    """``fill`` (default method) writes OUT.EXT.std.csv; ``qc IN OUT`` then gives the verdicts of
    ``qc --std``, says where the estimate came from, and ignores one older than the fill."""
    X = walk(200, 6, seed=1)
    X[60:75, 2] = np.nan
    X[120:124, 4] = np.nan
    src, out = tmp_path / "a.npz", tmp_path / "a_filled.npz"
    np.savez(src, points=X, labels=np.array([f"M{j}" for j in range(6)]), rate=100.0)
    assert main(["fill", str(src), "-o", str(out), "-q"]) == 0
    side = tmp_path / "a_filled.npz.std.csv"
    assert side.is_file()
    capsys.readouterr()
    report = ["-o", str(tmp_path / "r.html")]
    assert main(["qc", str(src), str(out), *report]) == 0
    text = capsys.readouterr().out
    assert f"estimate: {side} (written by 'torchfill fill' beside {out})" in text
    assert "no error estimate given" not in text
    assert main(["qc", str(src), str(out), "--json", "-", *report, "-q"]) == 0
    found = json.loads(capsys.readouterr().out)
    assert main(["qc", str(src), str(out), "--std", str(side), "--json", "-", *report, "-q"]) == 0
    assert found == json.loads(capsys.readouterr().out)
    assert all(r["est_rmse"] is not None for r in found)
    assert main(["fill", str(src), "-o", str(out), "-m", "pchip", "-q"]) == 0     # no estimate
    capsys.readouterr()
    assert main(["qc", str(src), str(out), *report]) == 0
    text = capsys.readouterr().out
    assert f"estimate: none: {side} is older than {out}" in text
    assert main(["fill", str(src), "-o", str(tmp_path / "b.npz"), "--std", "none", "-q"]) == 0
    assert not (tmp_path / "b.npz.std.csv").exists()


def test_qc_counts_unfilled_samples_as_the_fill_does(tmp_path, capsys):
    """One count of unfilled samples: a marker never observed is counted by qc too."""
    X = body()
    X[250:, 1] = np.nan                   # a trial end beyond the extrapolation limit
    X[:, 3] = np.nan                      # never observed
    src = tmp_path / "a.npz"
    np.savez(src, points=X, labels=np.array([f"M{j}" for j in range(6)]), rate=100.0)
    out = tmp_path / "b.npz"
    assert main(["fill", str(src), "-o", str(out), "-m", "linear", "--extrapolate", "0.1"]) == 0
    said = capsys.readouterr()
    left = int(torchfill.read(out).mask.sum())
    assert left >= 300 and f"{left} left unfilled" in said.out
    assert main(["qc", str(src), str(out), "-o", str(tmp_path / "r.html"), "-m", "linear"]) == 0
    assert f"; {left} missing sample(s) left unfilled" in capsys.readouterr().out


def _flagged(rows) -> dict:
    return {(r["marker"], r["first_frame"], r["last_frame"]): r["verdict"] for r in rows
            if r["verdict"] != "ok"}


@pytest.mark.parametrize("name", [n if n == "c3dorg_s04_sub_labels.c3d" else
                                  pytest.param(n, marks=pytest.mark.slow)
                                  for n in PLAUSIBLE_FILES])
def test_qc_without_std_flags_every_gap_the_fill_flagged(name, recording, tmp_path, capsys):
    """On every real recording with gaps: ``qc IN FILLED`` with no ``--std`` flags (check or
    reject) every gap that the fill's own verdicts (``fill --report-json``: the fill and its
    estimate in memory) flag, with the same verdict, and the same as ``qc --std``; a C3D output
    records those verdicts in its TORCHFILL group."""
    src = recording(name)
    out = tmp_path / f"filled{src.suffix}"
    fill_json, report = tmp_path / "fill.json", ["-o", str(tmp_path / "r.html")]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["fill", str(src), "-o", str(out), "--report-json", str(fill_json),
                     "-q", "-q"]) == 0
        own = json.loads(fill_json.read_text())
        capsys.readouterr()
        assert main(["qc", str(src), str(out), "--json", "-", *report, "-q"]) == 0
        found = json.loads(capsys.readouterr().out)
        side = ["--std", f"{out}.std.csv"]
        assert main(["qc", str(src), str(out), *side, "--json", "-", *report, "-q"]) == 0
        given = json.loads(capsys.readouterr().out)
    assert found == given
    assert _flagged(found) == _flagged(own)
    if src.suffix == ".c3d":
        back, seq = torchfill.read(out), torchfill.read(src)
        rows = _json_rows(seq, back, found)
        np.testing.assert_array_equal(back.meta["verdict"], qc.sample_verdicts(rows, back.points))


def _json_rows(seq, back, found):
    """The JSON rows of ``qc --json`` as gap rows (index, frames as indices, verdict); a label
    that several markers share (walking_hybrid_2's three ``L_THIGH_3``) goes to the first of them
    missing there that no earlier row of the same frames took."""
    first, taken, rows = int(seq.first_frame or 0), set(), []
    for r in found:
        start = r["first_frame"] - first
        j = next(j for j, label in enumerate(seq.labels) if label == r["marker"]
                 and seq.mask[start, j] and (j, start) not in taken)
        taken.add((j, start))
        rows.append({"j": j, "start": start, "stop": r["last_frame"] - first + 1,
                     "verdict": r["verdict"]})
    return rows
