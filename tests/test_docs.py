"""The documentation stays true: every block marked ``bash example`` or ``python example`` in the
README and docs/ runs (in a scratch folder where ``trial.c3d`` is the embedded sample with
simulated gaps, and ``torchfill`` is this checkout's CLI; tags after ``example``: ``needs-data``
skips without the shared recordings, ``needs-interop`` without pandas and xarray), every relative
link resolves, the generated pages are up to date, and the README stays short and speaks of the
software only."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import torchfill
from torchfill import gaps
from torchfill.data import data_dir

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```(?P<info>[^\n]*)\n(?P<body>.*?)^```", re.S | re.M)
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")


def _blocks():
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for m in FENCE.finditer(text):
            words = m.group("info").split()
            if len(words) >= 2 and words[1] == "example":
                line = text[: m.start()].count("\n") + 1
                yield pytest.param(words[0], set(words[2:]), m.group("body"),
                                   id=f"{page.relative_to(ROOT)}:{line}")


@pytest.fixture(scope="module")
def trial(gappy_sample) -> Path:
    """``trial.c3d``: the embedded sample with 10 markers' simulated gaps, as a fresh C3D."""
    return gappy_sample


@pytest.fixture(scope="module")
def shim(tmp_path_factory) -> Path:
    """A folder with a ``torchfill`` command that runs this checkout's CLI."""
    folder = tmp_path_factory.mktemp("bin")
    cmd = folder / "torchfill"
    cmd.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m torchfill "$@"\n')
    cmd.chmod(0o755)
    return folder


@pytest.mark.slow                    # the pages' examples fill whole recordings
@pytest.mark.parametrize("language, tags, body", list(_blocks()))
def test_example_runs(language, tags, body, trial, shim, tmp_path):
    if "needs-data" in tags and not data_dir(ROOT).is_dir():
        pytest.skip("needs the shared recordings")
    if "needs-interop" in tags:                     # the `interop` extra: pandas, xarray
        pytest.importorskip("pandas")
        pytest.importorskip("xarray")
    work = tmp_path / "work"
    work.mkdir()
    (work / "trial.c3d").write_bytes(trial.read_bytes())
    (work / "experiments").symlink_to(ROOT / "experiments")
    env = dict(os.environ, PATH=f"{shim}{os.pathsep}{os.environ.get('PATH', '')}",
               PYTHONPATH=str(ROOT), OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "1"),
               TORCHFILL_DATA=str(data_dir(ROOT)), MPLBACKEND="Agg")
    if language in ("bash", "sh"):
        cmd = ["bash", "-euo", "pipefail", "-c", body]
    elif language == "python":
        cmd = [sys.executable, "-c", body]
    else:
        pytest.fail(f"unknown example language {language!r}")
    done = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, f"exit {done.returncode}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    assert "Traceback" not in done.stderr


def test_there_are_examples():
    kinds = {(p.values[0], str(p.id).split(":")[0]) for p in _blocks()}
    assert ("bash", "README.md") in kinds and ("python", "README.md") in kinds


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    return {_slug(m.group(1)) for m in re.finditer(r"^#{1,6} (.+)$", text, re.M)}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page):
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    text = re.sub(r"`[^`\n]*`", "", text)
    broken = []
    for m in LINK.finditer(text):
        target = m.group(1) or m.group(2)
        if re.match(r"[a-z]+:", target):              # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(target)
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            broken.append(target)
    assert not broken, f"{page.name}: broken links {broken}"


def test_generated_pages_are_up_to_date():
    done = subprocess.run([sys.executable, "-m", "benchmarks", "docs", "--check"], cwd=ROOT,
                          capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert done.returncode == 0, ("run `python -m benchmarks docs`:\n" + done.stdout
                                  + done.stderr[-2000:])


def test_readme_is_short_and_about_the_software():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 200
    for page in PAGES:
        body = page.read_text(encoding="utf-8")
        for pattern in (r"\b20\d\d-\d\d-\d\d\b", r"\b[Ii]ssue #?\d", r"/work/", r"\bthe lead\b",
                        r"\bhelper\b", r"\bload average\b"):
            found = re.search(pattern, body)
            assert not found, f"{page.name}: {found.group(0)!r}"


CODE_LINK = re.compile(r"\b((?:docs|experiments/results)/[\w./-]*[\w/-](?:#[\w-]+)?)")


def test_links_from_code_comments_into_docs_and_results_resolve():
    """Module comments and docstrings keep one line and a link to docs/ or experiments/results/
    (the numbers live there): every such link names a file or folder that exists, and an anchor
    one of the page's headings."""
    broken = []
    for path in sorted([*(ROOT / "torchfill").rglob("*.py"), *(ROOT / "benchmarks").rglob("*.py")]):
        for m in CODE_LINK.finditer(path.read_text(encoding="utf-8")):
            target, _, anchor = m.group(1).partition("#")
            dest = ROOT / target.rstrip(".")
            if not dest.exists():
                broken.append(f"{path.relative_to(ROOT)}: {m.group(1)}")
            elif anchor and anchor not in _anchors(dest):
                broken.append(f"{path.relative_to(ROOT)}: {m.group(1)}")
    assert not broken, broken


SCRIPT = re.compile(r"(?<![\w./-])((?:[\w-]+/)*[A-Za-z_]\w*\.(?:py|sh))\b")
#: Files of other projects a docstring names (MoGapFill's module, fetched by the user).
OTHER_PROJECTS = {"smooth.py"}


def test_code_names_only_scripts_and_modules_that_exist():
    """A comment or docstring that names a program (``scripts/x.py``, ``bench_x.py``) names one
    in the repository: a path from the root or the package, or the name of a tracked file;
    programs that were removed are named by the suite that replaced them
    (``python -m benchmarks SUITE``) or a page of docs/."""
    names = {p.name for p in ROOT.rglob("*") if ".venv" not in p.parts and ".git" not in p.parts}
    broken = []
    for path in sorted([*(ROOT / "torchfill").rglob("*.py"), *(ROOT / "benchmarks").rglob("*.py")]):
        for m in SCRIPT.finditer(path.read_text(encoding="utf-8")):
            name = m.group(1)
            if "/" in name:
                ok = (ROOT / name).exists() or (ROOT / "torchfill" / name).exists()
            else:
                ok = name in names or name in OTHER_PROJECTS
            if not ok:
                broken.append(f"{path.relative_to(ROOT)}: {name}")
    assert not broken, broken


MEASURED = re.compile(r"\d(?:\.\d+)?\s*(?:mm|ms|s|°|%|MB|GB|x|×)(?!\w)")
GENERATED_PART = re.compile(r"<!-- (\w+):start -->.*?<!-- \1:end -->"
                            r"|<!-- table: [^ ]+ -->.*?<!-- end table -->", re.S)


def test_measured_tables_in_docs_are_generated():
    """A table of docs/ or the README that quotes a measurement (mm, s, °, %, MB, x) is generated from stored
    rows by ``python -m benchmarks docs`` (between its block markers); measurements of earlier
    code live in experiments/results/. A table of definitions (``| column | meaning |``) may
    name the thresholds it defines."""
    quoted = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = GENERATED_PART.sub("", page.read_text(encoding="utf-8"))
        for table in re.finditer(r"(?:^\|.*\n)+", text, re.M):
            lines = table.group(0).splitlines()
            if lines[0].replace(" ", "") == "|column|meaning|":
                continue
            quoted += [f"{page.name}: {line[:80]}" for line in lines if MEASURED.search(line)][:1]
    assert not quoted, quoted
