"""The [experiments] extra (Lightning, PyYAML, matplotlib) stays out of ``import torchfill`` and of
``torchfill fill``: a fresh interpreter fills a file and none of them is in ``sys.modules``."""
from __future__ import annotations

import subprocess
import sys

from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

EXTRA = ("pytorch_lightning", "lightning", "yaml", "matplotlib")


def test_fill_imports_nothing_from_the_experiments_extra(tmp_path):
    X = np.random.default_rng(0).normal(size=(60, 4, 3))
    X[20:30, 1] = np.nan
    src, out = tmp_path / "t.npz", tmp_path / "t_filled.npz"
    np.savez(src, points=X, labels=np.array(["A", "B", "C", "D"]), rate=100.0, units="mm")
    probe = (f"import sys\nimport torchfill\nfrom torchfill.cli import main\n"
             f"assert main(['fill', {str(src)!r}, '-o', {str(out)!r}, '--method', 'linear']) == 0\n"
             f"assert torchfill.__file__.startswith({str(REPO)!r})\n"
             f"print('LOADED:' + ','.join(m for m in {EXTRA!r} if m in sys.modules))")
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         env={"OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-500:]
    assert run.stdout.strip().splitlines()[-1] == "LOADED:"
    assert out.exists()
