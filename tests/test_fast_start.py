"""Fast start: the CLI's help, ``info`` and ``methods`` run without importing torch, tensorly or
Lightning; ``import torchfill`` never imports Lightning; the static method list is the registry."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

HEAVY = ("torch", "tensorly", "lightning", "pytorch_lightning")


def _imported_after(code: str, heavy: tuple[str, ...] = HEAVY) -> set[str]:
    """Modules of ``heavy`` in ``sys.modules`` after running ``code`` in a fresh interpreter."""
    probe = (f"import sys\n{code}\n"
             f"print('HEAVY:' + ','.join(m for m in {heavy!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    line = out.stdout.strip().splitlines()[-1]
    assert line.startswith("HEAVY:"), out.stdout[-300:]
    return set(filter(None, line[len("HEAVY:"):].split(",")))


@pytest.fixture
def small_npz(tmp_path):
    X = np.random.default_rng(0).normal(size=(50, 4, 3))
    X[10:20, 1] = np.nan
    path = tmp_path / "t.npz"
    np.savez(path, points=X, labels=np.array(["A", "B", "C", "D"]), rate=100.0, units="mm")
    return path


@pytest.mark.parametrize("argv", [["--help"], ["methods"], ["fill", "--help"]])
def test_cli_starts_without_torch(argv):
    code = ("from torchfill.cli import main\n"
            f"try:\n    main({argv!r})\nexcept SystemExit:\n    pass")
    assert _imported_after(code) == set()
    assert _imported_after(code, heavy=("numpy",)) == set()     # help and names need no NumPy


def test_info_runs_without_torch(small_npz):
    code = f"from torchfill.cli import main\nassert main(['info', {str(small_npz)!r}]) == 0"
    assert _imported_after(code) == set()


def test_fill_imports_no_optional_package(small_npz, tmp_path):
    """A plain fill pays for torch and NumPy only: SciPy, TensorLy, Lightning, the plots, pandas
    and YAML wait until a method or command uses them."""
    optional = ("scipy", "tensorly", "lightning", "pytorch_lightning", "matplotlib", "pandas",
                "yaml", "ezc3d", "opensim")
    argv = ["fill", str(small_npz), "-m", "linear", "-o", str(tmp_path / "out.npz")]
    code = f"from torchfill.cli import main\nassert main({argv!r}) == 0"
    assert _imported_after(code, heavy=optional) == set()


def test_catalog_mentions_every_method():
    """The fill's quick name test (no source parsing) never rules out a registered method."""
    import torchfill
    from torchfill._catalog import mentioned

    assert all(mentioned(name) for name in torchfill.methods())
    assert not mentioned("no_such_method")


def test_import_torchfill_is_light_and_fill_still_works():
    assert _imported_after("import torchfill") == set()
    loaded = _imported_after("import torchfill\nassert 'tucker_tnn' in torchfill.methods()")
    assert "torch" in loaded and "lightning" not in loaded and "pytorch_lightning" not in loaded


def test_static_method_list_is_the_registry():
    """The catalog read from the sources agrees with the live classes: names, summaries (whole
    first sentences of the docstrings), training data, 2-D support, a speed class for each."""
    import numpy as np

    import torchfill
    from torchfill._catalog import SPEED, catalog, default
    from torchfill.solvers import base

    listed = catalog()
    assert [e.name for e in listed] == torchfill.methods()
    assert set(SPEED) == set(torchfill.methods()) and default() == torchfill.default_method()
    X = np.random.default_rng(0).normal(size=(40, 5, 2))
    X[10:15, 1] = np.nan
    for e in listed:
        cls = base._REGISTRY[e.name]
        doc = " ".join((cls.__doc__ or "").split())
        assert doc.startswith(e.summary.rstrip(".")) and e.summary.endswith("."), e.name
        assert e.training == ("training" in cls.fit_data), e.name
        if not e.planar:
            with pytest.raises(ValueError, match="3-D"):
                torchfill.fill(X, e.name, constraints=False)
    for name in ("linear", "pchip", "svt"):
        assert next(e for e in listed if e.name == name).planar
        torchfill.fill(X, name, constraints=False)


def test_methods_cli_lists_every_registered_method(capsys):
    """One row per method, the default marked, columns for speed, 2-D and training; summaries
    are whole sentences (continued on the next lines, never cut)."""
    import torchfill
    from torchfill._catalog import catalog
    from torchfill.cli import main

    assert main(["methods"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["method", "speed", "2-D", "training", "summary"]
    rows = [line for line in lines[1:] if line[:1].strip() and not line.startswith("*")]
    assert [row.split()[0] for row in rows] == torchfill.methods()
    default = next(row for row in rows if row.split()[1] == "*")
    assert default.split()[0] == torchfill.default_method()
    assert lines[-1].startswith("*") or any(line.startswith("* the default") for line in lines)
    text = " ".join(" ".join(lines).split())
    for e in catalog():
        assert " ".join(e.summary.replace("``", "").split()) in text, e.name
