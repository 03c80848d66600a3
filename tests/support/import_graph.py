"""The package's import graph, read from the source (no module is imported): every ``demoforge`` module,
every import statement between them (at module level, under ``if``/``try``, ``TYPE_CHECKING`` and inside
functions), the rooms they live in. Used by tests/test_architecture.py and by the scripts that count and
draw the structure (scripts/architecture_counts.py, scripts/draw_layers.py), on this checkout or another.
"""

from __future__ import annotations

import ast
from pathlib import Path

DESIGN_CARD = ("lib", "tasks", "flows", "schemas")


def find_modules(root: Path) -> dict[str, Path]:
    """{dotted name: file} of the package in the checkout at ``root``: demoforge/ and the design card's
    folders, wherever their real files are (inside demoforge/, or at the top with a mapping); symbolic
    links are not followed, so no file counts twice."""
    out: dict[str, Path] = {}
    tops = [(["demoforge"], root / "demoforge")]
    tops += [(["demoforge", t], root / t) for t in DESIGN_CARD if (root / t).is_dir() and not (root / t).is_symlink()]
    for prefix, folder in tops:
        for p in sorted(folder.rglob("*.py")):
            rel = p.relative_to(folder)
            if any((folder / Path(*rel.parts[:i])).is_symlink() for i in range(1, len(rel.parts))):
                continue
            parts = list(rel.with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(prefix + parts)] = p
    return out


def import_nodes(tree: ast.Module) -> list[ast.Import | ast.ImportFrom]:
    """Every import statement of a module (a lazy import is an import: it ties the modules together all the same)."""
    return [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]


def imported(name: str, path: Path, modules: dict[str, Path]) -> list[tuple[str, str | None, int]]:
    """(module of the package, name taken from it or None, line) for every import in ``name``'s file."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for n in import_nodes(tree):
        if isinstance(n, ast.Import):
            targets = [(a.name, None) for a in n.names]
        else:
            base = n.module or ""
            if n.level:
                up = package.split(".")[: len(package.split(".")) - (n.level - 1)]
                base = ".".join(up + ([n.module] if n.module else []))
            # `from a.b import c`: module a.b.c when c is one, else name c of module a.b
            targets = [(f"{base}.{a.name}", None) if f"{base}.{a.name}" in modules else (base, a.name)
                       for a in n.names]
        out += [(t, what, n.lineno) for t, what in targets if t in modules and t != name]
    return out


def room(module: str) -> str:
    """The room a module lives in: lib's subfolders one by one (lib.takes, lib.sim, ...), else the layer."""
    parts = module.split(".")
    return ".".join(parts[:3]) if len(parts) > 2 and parts[1] == "lib" else ".".join(parts[:2])


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found
