"""The package's imports point down only (DESIGN.md, "Layout and one-way dependencies"): a module
may import from its own layer or the layers below, never from a layer above, lazily or not."""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "torchfill"

#: Layer of each top-level part, bottom first. Parts of one layer may import one another.
LAYERS = [
    {"sequence", "gaps", "metrics", "ops", "runtime", "_catalog"},
    {"io", "data", "projection", "segments", "segment_names", "training"},
    {"solvers"},
    {"windows", "constraints", "qc", "options", "unfilled"},
    {"filling", "kinds", "batch", "progress"},
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
                elif mod == "torchfill":                     # ``from torchfill import qc``
                    found.update(a.name for a in node.names)
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



def _name(path: Path) -> str:
    rel = path.relative_to(PACKAGE).with_suffix("")
    return ".".join(["torchfill", *rel.parts]).removesuffix(".__init__")


def _modules(path: Path, top_only: bool = False) -> set[str]:
    """Dotted torchfill modules ``path`` imports: ``from torchfill.x import y`` counts as
    ``torchfill.x.y`` when that is a module, else as ``torchfill.x``; ``top_only``: the imports
    at module level only."""
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_only else list(ast.walk(tree))
    package = _name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    found = set()
    for node in nodes:
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1] + \
                    (node.module.split(".") if node.module else [])
            else:
                base = (node.module or "").split(".")
            if base[:1] != ["torchfill"]:
                continue
            for a in node.names:
                sub = PACKAGE.joinpath(*base[1:], a.name)
                is_module = sub.with_suffix(".py").exists() or sub.is_dir()
                found.add(".".join([*base, a.name]) if is_module else ".".join(base))
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("torchfill"))
    return found


def test_filling_knows_the_solver_contract_only():
    """``fill()`` reaches solvers through the package's face and the contract module (the
    registry, ``Solver``) alone."""
    inner = sorted(m for m in _modules(PACKAGE / "filling.py")
                   if m.startswith("torchfill.solvers.") and m != "torchfill.solvers.base")
    assert not inner, f"filling.py imports solver modules: {inner}"
    lines = len((PACKAGE / "filling.py").read_text().splitlines())
    assert lines <= 500, f"filling.py has {lines} lines: the facade stays small (at most 500)"


def test_no_import_cycle_between_modules():
    """No cycle among the package's modules through their module-level imports (lazy imports
    inside functions must still point down: see above)."""
    graph = {_name(path): _modules(path, top_only=True) for path in sorted(PACKAGE.rglob("*.py"))}
    done, stack, cycles = set(), [], []

    def visit(node):
        if node in stack:
            cycles.append(stack[stack.index(node):] + [node])
            return
        if node in done:
            return
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt != node:
                visit(nxt)
        stack.pop()
        done.add(node)

    for node in sorted(graph):
        visit(node)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles[:5])


#: Longest module (lines) and function body (lines, docstring aside) in the package.
MAX_MODULE, MAX_BODY = 700, 80
#: Files still over those sizes, being split by their owners' work; remove an entry once it fits.
OVERSIZED: set[str] = set()


def _body_lines(node) -> int:
    body = node.body
    if len(body) > 1 and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
            and isinstance(body[0].value.value, str):
        body = body[1:]
    return body[-1].end_lineno - body[0].lineno + 1


def test_modules_and_functions_stay_short():
    """No module of the package over MAX_MODULE lines, no function body over MAX_BODY lines."""
    long = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        if rel in OVERSIZED:
            continue
        text = path.read_text()
        if len(text.splitlines()) > MAX_MODULE:
            long.append(f"{rel}: {len(text.splitlines())} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and \
                    _body_lines(node) > MAX_BODY:
                long.append(f"{rel}:{node.lineno} {node.name}: {_body_lines(node)} lines")
    assert not long, "too long:\n" + "\n".join(long)


def test_every_lazy_submodule_exists():
    """``torchfill.NAME`` after a bare ``import torchfill`` works for every name it offers."""
    import torchfill

    for name in sorted(torchfill._SUBMODULES):
        assert getattr(torchfill, name).__name__ == f"torchfill.{name}"
    assert not hasattr(torchfill, "rigid")          # the rigid method lives in torchfill.solvers
