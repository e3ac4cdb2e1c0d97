"""The registered methods, read from the solver sources without importing them (no torch), so that
``torchfill methods`` and the command line's name checks start fast.

A method is a class decorated with ``@register`` in ``torchfill/solvers/*.py`` whose body sets
``name = "..."``; its summary is the first sentence of its docstring. Methods come in registration
order: modules in the order ``solvers/__init__.py`` names them, classes in source order. What a
method takes is read from its class and the classes it derives from in the same module:
``fit_data`` naming ``training`` (it learns from other recordings), a ``require_3d(...)`` call
(3-D markers only). ``tests/test_fast_start.py`` checks all of it against the live registry.
"""
from __future__ import annotations

import ast
import difflib
import re
from dataclasses import dataclass
from pathlib import Path

SOLVERS = Path(__file__).parent / "solvers"
OPTIONS = Path(__file__).parent / "options.py"

#: Speed class of each method: ``fast`` about a second or less on 3000 frames x 41 markers,
#: ``medium`` a few seconds, ``slow`` tens of seconds (measurements: docs/speed.md).
SPEED = {
    "linear": "fast", "spline": "fast", "pchip": "fast", "pca_train": "fast",
    "pca_blackout": "fast", "pca_gloersen": "fast", "glr": "fast", "li": "fast", "lpr": "fast",
    "lgrnn": "fast", "pma": "fast",
    "svt": "medium", "trnn": "medium", "trnn_d2": "medium", "tucker": "medium",
    "tucker_tnn": "medium", "cp": "medium", "smooth_cp": "medium", "sparse_cp": "medium",
    "halrtc": "medium", "pstnn": "medium", "rigid": "medium",
    "spc": "slow", "grad_tucker": "slow", "grad_cp": "slow", "auto": "slow",
}


@dataclass(frozen=True)
class Entry:
    """One registered method as the sources declare it."""
    name: str
    summary: str             # the docstring's first sentence
    planar: bool             # takes 2-D keypoints (T, J, 2) too
    training: bool           # learns from other recordings (``training=``, ``--training``)

    @property
    def speed(self) -> str:
        return SPEED.get(self.name, "?")


def entries() -> list[tuple[str, str]]:
    """``(name, summary)`` of every registered method, in registration order."""
    return [(e.name, e.summary) for e in catalog()]


def catalog() -> list[Entry]:
    """Every registered method, in registration order."""
    order = (SOLVERS / "__init__.py").read_text(encoding="utf-8")
    modules = sorted(SOLVERS.glob("*.py"),
                     key=lambda p: (order.find(f'"{p.stem}"') % (len(order) + 1), p.stem))
    return [entry for path in modules for entry in _registered(path)]


def default() -> str:
    """The default method: the first of ``options.DEFAULT_METHODS`` that is registered."""
    tree = ast.parse(OPTIONS.read_text(encoding="utf-8"))
    names = {e.name for e in catalog()}
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "DEFAULT_METHODS" for t in node.targets):
            return next(m for m in ast.literal_eval(node.value) if m in names)
    raise LookupError("DEFAULT_METHODS not found in options.py")


def mentioned(name: str) -> bool:
    """Whether ``name`` appears quoted in a solver source: a quick test before :func:`entries`,
    which parses them all (0.1-0.2 s of a fill's start-up). A registered name written plainly
    always appears; False leaves the verdict to :func:`entries`."""
    quoted = (f'"{name}"', f"'{name}'")
    texts = (path.read_text(encoding="utf-8") for path in SOLVERS.glob("*.py"))
    return any(q in text for text in texts for q in quoted)


def resolve(name: str, names: list[str] | None = None) -> str:
    """The registered spelling of method ``name`` (case and ``-`` for ``_`` forgiven); a one-line
    ``ValueError`` with a "did you mean" otherwise. ``names``: the registered names when known
    (default: read from the sources)."""
    key = str(name).strip().lower().replace("-", "_")
    if names is None and mentioned(key):
        names = [key] if key in (e.name for e in catalog()) else None
    if names is None:
        names = [e.name for e in catalog()]
    if key in names:
        return key
    close = difflib.get_close_matches(key, names, n=1)
    raise ValueError(f"unknown method {name!r}" + (f"; did you mean {close[0]!r}?" if close else "")
                     + " ('torchfill methods' lists them)")


def _registered(path: Path) -> list[Entry]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    classes = {node.name: node for node in tree.body if isinstance(node, ast.ClassDef)}
    found = []
    for node in classes.values():
        if any(isinstance(d, ast.Name) and d.id == "register" for d in node.decorator_list):
            name = _class_name_attr(node)
            if name:
                lineage = _lineage(node, classes)
                found.append(Entry(name, _sentence(ast.get_docstring(node) or ""),
                                   planar=not any(_calls(c, "require_3d") for c in lineage),
                                   training=any("training" in _fit_data(c) for c in lineage)))
    return found


def _lineage(node: ast.ClassDef, classes: dict) -> list[ast.ClassDef]:
    """``node`` and its bases defined in the same module, nearest first."""
    out, todo = [], [node]
    while todo:
        cls = todo.pop(0)
        out.append(cls)
        todo += [classes[b.id] for b in cls.bases if isinstance(b, ast.Name) and b.id in classes]
    return out


def _calls(node: ast.ClassDef, method: str) -> bool:
    return any(isinstance(n, ast.Attribute) and n.attr == method for n in ast.walk(node))


def _fit_data(node: ast.ClassDef) -> tuple:
    for stmt in node.body:
        if isinstance(stmt, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "fit_data" for t in stmt.targets):
            try:
                return tuple(ast.literal_eval(stmt.value))
            except ValueError:
                return ()
    return ()


def _sentence(doc: str) -> str:
    """The first sentence of a docstring's first paragraph, on one line: up to a full stop
    followed by a capital letter or the end (not one inside a ``code`` span)."""
    paragraph = " ".join(doc.strip().split("\n\n")[0].split())
    paragraph = re.sub(r"::$", ".", paragraph)
    code = [m.span() for m in re.finditer(r"``.*?``", paragraph)]
    for m in re.finditer(r"\.(?=\s+[A-Z]|$)", paragraph):
        if not any(a <= m.start() < b for a, b in code):
            return paragraph[:m.end()]
    return paragraph


def _class_name_attr(node: ast.ClassDef) -> str | None:
    for stmt in node.body:
        targets = stmt.targets if isinstance(stmt, ast.Assign) else \
            [stmt.target] if isinstance(stmt, ast.AnnAssign) else []
        if any(isinstance(t, ast.Name) and t.id == "name" for t in targets) and \
                isinstance(stmt.value, ast.Constant) and isinstance(stmt.value.value, str):
            return stmt.value.value
    return None
