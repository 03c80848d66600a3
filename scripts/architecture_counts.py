"""Count what tests/test_architecture.py checks, on this checkout or another (e.g. an older commit's
worktree), for before/after comparisons: modules, import edges at module level and inside functions,
module and room loops, private names imported across files and rooms, functions over 120 lines; and what
issue 44 asks about: import statements inside functions (of demoforge's own modules / all), the
`import demoforge.lib  # noqa` lines, package-init loops, name registries, MuJoCo stepping loops (engines),
`open_take` call sites in the stages and flows, lib modules without a test file named after them; and issue 44's
item 7, where the tests live (tests/support/mirror.py, tests/support/tested_through.py): modules with their
mirrored test file, modules covered only through the table (a test file that imports them by name), reached
by a test without one of their own, exempt, and with no test; for the whole package and for lib/. A checkout
without the table (before the tests were mirrored) counts its mirrored files and, in place of the table's
kinds; both count the modules without a mirrored file that some test file imports by name.

    .venv/bin/python scripts/architecture_counts.py [--root CHECKOUT]
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.support.import_graph import cycles, find_modules, imported, room  # noqa: E402
from tests.support.mirror import direct_imports, mirrored_test  # noqa: E402


def _calls(tree: ast.AST, name: str) -> int:
    """Calls of `name` (a function or a method of that name) in a module."""
    return sum(1 for n in ast.walk(tree) if isinstance(n, ast.Call) and (
        (isinstance(n.func, ast.Name) and n.func.id == name) or (isinstance(n.func, ast.Attribute) and n.func.attr == name)))


def _function_imports(tree: ast.Module) -> tuple[int, int]:
    """(import statements inside functions that import demoforge's own modules, all of them)."""
    own = every = 0
    for f in ast.walk(tree):
        if not isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for n in ast.walk(f):
            if isinstance(n, (ast.Import, ast.ImportFrom)):
                every += 1
                names = [a.name for a in n.names] if isinstance(n, ast.Import) else [n.module or ""]
                own += bool(getattr(n, "level", 0)) or any(x.split(".")[0] == "demoforge" for x in names)
    return own, every


def _registries(tree: ast.Module) -> tuple[int, int]:
    """(`Registry(...)` instances, hand-written registries: module-level dicts whose name says registry /
    backends / sources / detectors / robots) a module defines."""
    shared = hand = 0
    for n in tree.body:
        target = n.targets[0] if isinstance(n, ast.Assign) and len(n.targets) == 1 else getattr(n, "target", None)
        value = getattr(n, "value", None)
        if not isinstance(target, ast.Name) or value is None:
            continue
        if isinstance(value, ast.Call) and getattr(value.func, "id", None) == "Registry":
            shared += 1
        elif isinstance(value, (ast.Dict, ast.DictComp)) and any(
                k in target.id.upper() for k in ("REGISTRY", "BACKENDS", "SOURCES", "DETECTORS", "ROBOTS")):
            hand += 1
    return shared, hand


def issue44_counts(root: Path, modules: dict[str, Path], edges: dict[str, set[str]]) -> dict:
    own = every = ritual = opens = 0
    engines, untested, shared, hand = [], [], [], []
    tests = {p.stem for p in (root / "tests").rglob("test_*.py")}
    for m, path in modules.items():
        text = path.read_text()
        tree = ast.parse(text)
        o, e = _function_imports(tree)
        own, every = own + o, every + e
        ritual += sum(1 for line in text.splitlines() if line.strip().startswith("import demoforge.lib  # noqa"))
        r = _registries(tree)
        shared += [m] * r[0]
        hand += [m] * r[1]
        if _calls(tree, "mj_step"):
            engines.append(m)
        if m.split(".")[1:2] in (["tasks"], ["flows"]):
            opens += _calls(tree, "open_take")
        if m.startswith("demoforge.lib.") and path.name != "__init__.py" and f"test_{path.stem}" not in tests:
            untested.append(m)
    inits = {m for m, p in modules.items() if p.name == "__init__.py"}
    init_loops = [c for c in cycles(edges) if inits & set(c)]
    return {"import statements inside functions (own modules / all)": f"{own} / {every}",
            "`import demoforge.lib  # noqa` lines": ritual, "package-init loops": init_loops,
            "Registry instances": shared, "hand-written registry dicts": hand,
            "modules stepping MuJoCo (mj_step)": engines,
            "open_take calls in tasks/ and flows/": opens,
            "lib modules without a tests/test_<module>.py": len(untested)}


def _table(root: Path) -> dict | None:
    """The checkout's tests/support/tested_through.py table (read from its file), or None where it has none."""
    import importlib.util

    path = root / "tests" / "support" / "tested_through.py"
    if not path.is_file():
        return None
    spec = importlib.util.spec_from_file_location(f"_tested_through_{abs(hash(str(root)))}", path)
    table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(table)
    return table.TESTED_THROUGH


def test_layout_counts(root: Path, modules: dict[str, Path]) -> dict:
    """Where each module's tests are: its mirrored file, the table's entry (its kind), or nowhere."""
    table = _table(root)
    tests = sorted((root / "tests").rglob("test_*.py"))
    imported_by_name = set().union(*(direct_imports(t, modules) for t in tests)) if tests else set()
    kinds: dict[str, str] = {}
    for m, path in modules.items():
        e = (table or {}).get(m)
        if (root / mirrored_test(m, path)).is_file():
            kinds[m] = "mirrored"
        elif e is not None:
            kinds[m] = ("through" if e.test else "reached" if e.reached_by else "exempt" if e.exempt else "untested")
        else:
            kinds[m] = "neither"
    out = {}
    for scope, names in (("package", list(modules)), ("lib", [m for m in modules if m.startswith("demoforge.lib.")])):
        n = {k: sum(1 for m in names if kinds[m] == k) for k in
             ("mirrored", "through", "reached", "exempt", "untested", "neither")}
        unmirrored = [m for m in names if kinds[m] != "mirrored"]
        out[f"{scope} modules with their mirrored test file (of {len(names)})"] = n["mirrored"]
        out[f"{scope} modules without one that a test file imports by name"] = sum(
            1 for m in unmirrored if m in imported_by_name)
        out[f"{scope} modules without one that no test file imports by name"] = sum(
            1 for m in unmirrored if m not in imported_by_name)
        if table is not None:
            out[f"{scope} modules covered only through the table (a test imports them by name)"] = n["through"]
            out[f"{scope} modules reached by a test, none of their own"] = n["reached"]
            out[f"{scope} modules exempt (nothing of their own to test)"] = n["exempt"]
            out[f"{scope} modules with no test"] = [m for m in names if kinds[m] in ("untested", "neither")]
    return out


def counts(root: Path) -> dict:
    modules = find_modules(root)
    edges: dict[str, set[str]] = {}
    at_top = in_functions = 0
    private_files, private_rooms, long_functions = [], [], []
    for m, path in modules.items():
        tree = ast.parse(path.read_text())
        top_lines = {n.lineno for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))}
        found = imported(m, path, modules)
        edges[m] = {t for t, _, _ in found}
        pairs = {(t, line in top_lines) for t, _, line in found}
        at_top += sum(1 for _, top in pairs if top)
        in_functions += sum(1 for _, top in pairs if not top)
        for t, what, _ in found:
            if what and what.startswith("_") and not what.startswith("__"):
                private_files.append((m, what))
                if room(t) != room(m):
                    private_rooms.append(f"{m} <- {t}.{what}")
        long_functions += [f"{m}.{n.name} ({n.end_lineno - n.lineno + 1})" for n in ast.walk(tree)
                           if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.end_lineno - n.lineno + 1 > 120]
    room_edges: dict[str, set[str]] = {}
    for m, ts in edges.items():
        room_edges.setdefault(room(m), set()).update(room(t) for t in ts if room(t) != room(m))
    return {"modules": len(modules), "module-level import edges": at_top, "import edges inside functions": in_functions,
            "module loops": cycles(edges), "room loops": cycles(room_edges),
            "private names imported across files": len(private_files),
            "private names imported across rooms": private_rooms, "functions over 120 lines": long_functions,
            **issue44_counts(root, modules, edges), **test_layout_counts(root, modules)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1], help="the checkout to count")
    for key, value in counts(ap.parse_args().root.resolve()).items():
        if isinstance(value, list):
            print(f"{key}: {len(value)}")
            for item in value:
                print(f"    {item}")
        else:
            print(f"{key}: {value}")


if __name__ == "__main__":
    main()
