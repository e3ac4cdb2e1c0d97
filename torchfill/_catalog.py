"""The registered method names and one-line summaries, read from the solver sources without
importing them (no torch), so that ``torchfill methods`` starts fast.

A method is a class decorated with ``@register`` in ``torchfill/solvers/*.py`` whose body sets
``name = "..."``; its summary is the first line of its docstring. Methods come in registration
order: modules in the order ``solvers/__init__.py`` names them, classes in source order.
``tests/test_catalog.py`` checks this list against the live registry.
"""
from __future__ import annotations

import ast
from pathlib import Path

SOLVERS = Path(__file__).parent / "solvers"


def entries() -> list[tuple[str, str]]:
    """``(name, summary)`` of every registered method, in registration order."""
    order = (SOLVERS / "__init__.py").read_text(encoding="utf-8")
    modules = sorted(SOLVERS.glob("*.py"),
                     key=lambda p: (order.find(f'"{p.stem}"') % (len(order) + 1), p.stem))
    return [entry for path in modules for entry in _registered(path)]


def mentioned(name: str) -> bool:
    """Whether ``name`` appears quoted in a solver source: a quick test before :func:`entries`,
    which parses them all (0.1-0.2 s of a fill's start-up). A registered name written plainly
    always appears; False leaves the verdict to :func:`entries`."""
    quoted = (f'"{name}"', f"'{name}'")
    texts = (path.read_text(encoding="utf-8") for path in SOLVERS.glob("*.py"))
    return any(q in text for text in texts for q in quoted)


def _registered(path: Path) -> list[tuple[str, str]]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found = []
    for node in tree.body:
        if isinstance(node, ast.ClassDef) and any(
                isinstance(d, ast.Name) and d.id == "register" for d in node.decorator_list):
            name = _class_name_attr(node)
            if name:
                doc = (ast.get_docstring(node) or "").strip()
                found.append((name, doc.splitlines()[0] if doc else ""))
    return found


def _class_name_attr(node: ast.ClassDef) -> str | None:
    for stmt in node.body:
        targets = stmt.targets if isinstance(stmt, ast.Assign) else \
            [stmt.target] if isinstance(stmt, ast.AnnAssign) else []
        if any(isinstance(t, ast.Name) and t.id == "name" for t in targets) and \
                isinstance(stmt.value, ast.Constant) and isinstance(stmt.value.value, str):
            return stmt.value.value
    return None
