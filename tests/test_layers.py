"""The package's imports point down only (DESIGN.md, "Layout and one-way dependencies"): a module
may import from its own layer or the layers below, never from a layer above, lazily or not."""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "torchfill"

#: Layer of each top-level part, bottom first. Parts of one layer may import one another.
LAYERS = [
    {"sequence", "gaps", "metrics", "ops", "runtime", "_catalog"},
    {"io", "data", "projection", "segments"},
    {"solvers"},
    {"windows", "constraints", "qc"},
    {"filling", "batch", "progress"},
    {"lightning", "cli", "__main__", "__init__"},
]


def _layer(part: str) -> int:
    return next(i for i, names in enumerate(LAYERS) if part in names)


def _part(path: Path) -> str:
    rel = path.relative_to(PACKAGE)
    return rel.parts[0].removesuffix(".py")


def _imported_parts(path: Path) -> set[str]:
    """Top-level torchfill parts a module imports (relative or absolute, at any depth)."""
    tree = ast.parse(path.read_text())
    depth = len(path.relative_to(PACKAGE).parts) - 1         # folders below the package
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level == 0:
                mod = node.module or ""
                if mod.startswith("torchfill."):
                    found.add(mod.split(".")[1])
                continue
            up = node.level - 1                              # folders up from this module's own
            if up > depth:
                continue
            here = list(path.relative_to(PACKAGE).parts[:depth - up])
            names = (node.module.split(".") if node.module else []) or [a.name for a in node.names]
            target = (here + names)[0] if here or names else None
            if not here and not node.module:                 # ``from . import x``
                found.update(a.name for a in node.names)
            elif target:
                found.add(target)
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("torchfill."):
                    found.add(a.name.split(".")[1])
    return found


def test_no_import_points_up():
    upward = []
    for path in sorted(PACKAGE.rglob("*.py")):
        part = _part(path)
        for other in _imported_parts(path):
            if other in {p for layer in LAYERS for p in layer} and _layer(other) > _layer(part):
                upward.append(f"{path.relative_to(PACKAGE)} imports {other}")
    assert not upward, "imports that point up:\n" + "\n".join(upward)
