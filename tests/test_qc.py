"""``torchfill qc``: one row per real gap with a verdict, an HTML report that a browser renders."""
from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

import torchfill
from torchfill import qc
from torchfill.cli import main


def test_gap_table_flags_a_teleport_and_an_extrapolated_gap():
    t = np.arange(300)[:, None, None] / 100.0
    X = np.concatenate([300 * np.sin(t + np.arange(4)[None, :, None]) + 100 * np.arange(3)] * 1,
                       axis=1)
    gappy = X.copy()
    gappy[100:140, 1] = np.nan           # interior gap, filled with a 600 mm jump
    gappy[280:, 2] = np.nan              # extrapolated gap, filled exactly
    filled = X.copy()
    filled[120:140, 1] += 600.0
    rows = {(r["marker"], r["start"]): r for r in qc.gap_table(gappy, filled, rate=100.0)}
    jump, end = rows[("1", 100)], rows[("2", 280)]
    assert jump["kind"] == "interpolated" and "teleport" in jump["verdict"]
    assert end["kind"] == "extrapolated" and "extrapolated" in end["verdict"]
    assert "teleport" not in end["verdict"]


def test_qc_cli_on_a_real_gap_file(recording, tmp_path, capsys):
    src = recording("c3dorg_s02_pc_real.c3d")
    filled = tmp_path / "pc_filled.c3d"
    report = tmp_path / "pc.html"
    assert main(["fill", str(src), "-o", str(filled), "-m", "pchip", "-q"]) == 0
    assert main(["qc", str(src), str(filled), "-o", str(report)]) == 0
    out = capsys.readouterr().out
    seq = torchfill.read(src)
    n_gaps = len([1 for j, a, b in torchfill.metrics.gap_runs(seq.mask)])
    kinds = [line.split()[3] for line in out.splitlines()[2:] if len(line.split()) > 3]
    assert sum(k in ("interpolated", "extrapolated") for k in kinds) == n_gaps
    page = report.read_text()
    assert page.startswith("<!doctype html>") and page.count("data:image/png;base64,") >= 1
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
