"""The package's layers point one way and its modules import no cycle.

Every ``import`` of an smcbayes module, at the top of a file or inside a function, is an
edge of the import graph.  A module may import modules of its own layer or of layers
below it; the graph of modules has no cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "smcbayes"

LAYERS: tuple[tuple[str, ...], ...] = (
    ("smcbayes.errors", "smcbayes.config", "smcbayes.units", "smcbayes.progress",
     "smcbayes.resources"),
    ("smcbayes.forward",),
    ("smcbayes.data", "smcbayes.plotting"),
    ("smcbayes.simulation",),
    ("smcbayes.run",),
    ("smcbayes.surrogate",),
    ("smcbayes.posterior",),
    ("smcbayes.diagnose",),
    ("smcbayes.report",),
    ("smcbayes.commands", "smcbayes.api"),
    ("smcbayes.cli",),
)
"""Bottom first: forward <- data <- simulation <- run <- surrogate <- posterior <- diagnose
<- report <- commands <- cli, with config and errors at the bottom."""


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def layer_of(module: str) -> int:
    best, depth = -1, -1
    for level, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > depth:
                best, depth = level, len(prefix)
    if best < 0:
        raise AssertionError(f"{module} belongs to no layer; add it to LAYERS")
    return best


def imports_of(path: Path, module: str) -> list[list[str]]:
    """smcbayes imports anywhere in ``path``: per statement, the names it may refer to
    (``from pkg import x`` refers to the module ``pkg.x`` if there is one, else to ``pkg``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: list[list[str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [[a.name] for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            for a in node.names:
                # a name of the package root other than its version is the lazy API: top layer
                root = "smcbayes.api" if base == "smcbayes" and a.name != "__version__" else base
                found.append([f"{base}.{a.name}", root])
    return [names for names in found if names[-1] == "smcbayes" or names[-1].startswith("smcbayes.")]


def graph() -> dict[str, set[str]]:
    files = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    edges: dict[str, set[str]] = {}
    for module, path in files.items():
        targets = set()
        for names in imports_of(path, module):
            name = next((n for n in names if n in files), names[-1])
            while name and name not in files:  # `import pkg.sub.name` of a non-module
                name = name.rpartition(".")[0]
            if name and name != module and name != "smcbayes":
                targets.add(name)
        edges[module] = targets
    return edges


def test_no_upward_import() -> None:
    upward = [f"{m} (layer {layer_of(m)}) imports {t} (layer {layer_of(t)})"
              for m, targets in graph().items() if m != "smcbayes" for t in sorted(targets)
              if layer_of(t) > layer_of(m)]
    assert not upward, "\n".join(upward)


def test_no_import_cycle() -> None:
    edges = graph()
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    assert not cycles, "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_checker_sees_a_cycle_and_an_upward_import(tmp_path: Path) -> None:
    """The checks above are not vacuous: they find planted violations."""
    pkg = tmp_path / "smcbayes"
    (pkg / "forward").mkdir(parents=True)
    (pkg / "forward" / "a.py").write_text("from smcbayes.report import b\n")
    (pkg / "report").mkdir()
    (pkg / "report" / "b.py").write_text("def f():\n    from smcbayes.forward import a\n")
    (pkg / "data").mkdir()
    (pkg / "data" / "c.py").write_text("from smcbayes import calibrate\n")
    (pkg / "api.py").write_text("")
    global PACKAGE
    saved = PACKAGE
    PACKAGE = pkg
    try:
        with pytest.raises(AssertionError, match="imports smcbayes.report.b"):
            test_no_upward_import()
        with pytest.raises(AssertionError, match=r"smcbayes.data.c \(layer 2\) imports smcbayes.api"):
            test_no_upward_import()
        with pytest.raises(AssertionError, match="import cycles"):
            test_no_import_cycle()
    finally:
        PACKAGE = saved
