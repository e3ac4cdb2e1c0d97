"""README.md's "Which method when" table and OpenSim figures are generated from the stored
results: a changed row changes the README's number, and a hand-edited number is rewritten (so
``python -m benchmarks docs --check`` fails on it, tests/test_docs.py)."""
from __future__ import annotations

import re
import shutil

import numpy as np

from benchmarks import readme
from benchmarks.rows import num, read_csv, write_csv
from benchmarks.suites import docs, real_gaps


def test_the_table_follows_the_stored_rows(tmp_path, monkeypatch):
    rows = read_csv(real_gaps.CSV)
    for r in rows:
        if r["method"] == "default":
            r["rmse"] = 2 * num(r["rmse"])
    write_csv(tmp_path / "rows.csv", rows)
    monkeypatch.setattr(real_gaps, "CSV", tmp_path / "rows.csv")
    mean = np.mean([r["rmse"] for r in rows if r["method"] == "default"])
    cases = len({r["case"] for r in rows})
    assert f"real gap patterns ({cases} cases): **{mean:.1f}** mean" in readme.which_method()


def test_a_hand_edited_readme_number_is_rewritten(tmp_path, monkeypatch):
    page = tmp_path / "README.md"
    shutil.copy(readme.README, page)
    text = page.read_text(encoding="utf-8")
    start = text.index("<!-- which_method:start -->")
    end = text.index("<!-- which_method:end -->")
    first = re.compile(r"\d+\.\d+").search(text, start, end)
    edited = text[:first.start()] + "9" + text[first.start():]
    monkeypatch.setattr(readme, "README", page)
    blocks = docs.suite_blocks()
    assert (page, "which_method") in blocks and (page, "opensim_ik") in blocks
    current = docs.targets()[page]                  # what the stored results give
    page.write_text(edited, encoding="utf-8")
    assert docs.targets()[page] == current != edited
