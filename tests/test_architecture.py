"""The layers of docs/architecture.md, checked on the source: no import cycles, no import back up a
layer, Prefect stages only in tasks/."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = {"demoforge": ROOT / "demoforge", "lib": ROOT / "lib", "tasks": ROOT / "tasks", "flows": ROOT / "flows",
           "schemas": ROOT / "schemas"}


def _modules() -> dict[str, Path]:
    out = {}
    for top, folder in FOLDERS.items():
        for p in sorted(folder.rglob("*.py")):
            parts = list(p.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            prefix = ["demoforge"] if top == "demoforge" else ["demoforge", top]
            out[".".join(prefix + parts)] = p
    return out


MODULES = _modules()


def _import_nodes(tree: ast.Module):
    """Every import statement of a module: at module level, under ``if``/``try``, ``TYPE_CHECKING``, and
    inside functions (a lazy import is an import: it ties the modules together all the same)."""
    return [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]


def _imported(name: str, path: Path) -> list[tuple[str, str | None, int]]:
    """(module of the package, name taken from it or None, line) for every import in ``name``'s file."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for n in _import_nodes(tree):
        if isinstance(n, ast.Import):
            targets = [(a.name, None) for a in n.names]
        else:
            base = n.module or ""
            if n.level:
                up = package.split(".")[: len(package.split(".")) - (n.level - 1)]
                base = ".".join(up + ([n.module] if n.module else []))
            # `from a.b import c`: module a.b.c when c is one, else name c of module a.b
            targets = [(f"{base}.{a.name}", None) if f"{base}.{a.name}" in MODULES else (base, a.name)
                       for a in n.names]
        out += [(t, what, n.lineno) for t, what in targets if t in MODULES and t != name]
    return out


def _imports(name: str, path: Path, module_level_only: bool = False) -> set[str]:
    """Modules of the package that ``name`` imports (anywhere in the file, or at module level only)."""
    if not module_level_only:
        return {t for t, _, _ in _imported(name, path)}
    top = {n.lineno for n in ast.parse(path.read_text()).body if isinstance(n, (ast.Import, ast.ImportFrom))}
    return {t for t, _, line in _imported(name, path) if line in top}


def _folder(module: str) -> str:
    """The room a module lives in: lib's subfolders one by one (lib.takes, lib.sim, ...), else the layer."""
    parts = module.split(".")
    return ".".join(parts[:3]) if len(parts) > 2 and parts[1] == "lib" else ".".join(parts[:2])


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles: list[list[str]] = []

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
                cycles.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return cycles


def _module_edges() -> dict[str, set[str]]:
    return {m: _imports(m, p) for m, p in MODULES.items()}


def test_no_import_loop_between_modules_counting_imports_inside_functions():
    assert _cycles(_module_edges()) == []


def test_no_import_loop_between_folders():
    edges: dict[str, set[str]] = {}
    for m, targets in _module_edges().items():
        edges.setdefault(_folder(m), set()).update(_folder(t) for t in targets if _folder(t) != _folder(m))
    assert _cycles(edges) == []


def test_no_private_name_is_imported_from_another_folder():
    """A leading underscore says "this file's business": another room that needs it needs a public name."""
    leaks = [f"{m}:{line} takes {what} from {t}" for m, p in MODULES.items() for t, what, line in _imported(m, p)
             if what and what.startswith("_") and not what.startswith("__") and _folder(t) != _folder(m)]
    assert leaks == []


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "demoforge"


# what each layer may import from the package (anywhere in the file, lazy imports included)
ALLOWED = {
    "lib": {"lib"},
    "schemas": {"lib", "schemas"},
    "tasks": {"lib", "schemas", "tasks"},
    "flows": {"lib", "schemas", "tasks", "flows", "runtime"},
}


# the one exception, and why: a synthetic take carries its ground truth as tables in their contracts
EXCEPTIONS = {("demoforge.lib.synth.take", "schemas")}


def test_no_import_runs_back_up_a_layer():
    wrong = []
    for m, p in MODULES.items():
        layer = _layer(m)
        if layer not in ALLOWED:
            continue
        for t in _imports(m, p, module_level_only=False):
            if _layer(t) not in ALLOWED[layer] and t != "demoforge" and (m, _layer(t)) not in EXCEPTIONS:
                wrong.append(f"{m} imports {t}")
    assert wrong == []


def test_the_domain_library_knows_no_prefect():
    users = [m for m, p in MODULES.items() if _layer(m) == "lib"
             and any(isinstance(n, (ast.Import, ast.ImportFrom)) and "prefect" in (
                 getattr(n, "module", None) or " ".join(a.name for a in n.names))
                 for n in ast.walk(ast.parse(p.read_text())))]
    assert users == []


def test_prefect_stages_live_in_tasks_only():
    outside = []
    for m, p in MODULES.items():
        for n in ast.walk(ast.parse(p.read_text())):
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for d in n.decorator_list:
                    f = d.func if isinstance(d, ast.Call) else d
                    if getattr(f, "id", getattr(f, "attr", None)) == "stage_task" and _layer(m) != "tasks":
                        outside.append(f"{m}.{n.name}")
    assert outside == []


def test_the_variations_cache_is_keyed_on_source_files_that_exist():
    from demoforge.tasks.variations import code_files

    files = code_files()
    assert [f for f in files if not f.is_file()] == []
    names = {f.relative_to(ROOT).as_posix() for f in files}
    assert {"lib/trajectories/retrieval.py", "lib/geometry/rotations.py", "lib/sim/executor.py"} <= names


MAX_MODULE_LINES = 600  # a module longer than this has more than one job: split it along its seams


def test_no_module_of_the_design_cards_folders_is_over_600_lines():
    design_card = {f"demoforge.{folder}" for folder in ("lib", "tasks", "flows", "schemas")}
    long = {name: n for name, path in MODULES.items() if ".".join(name.split(".")[:2]) in design_card
            and (n := len(path.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


MAX_FUNCTION_LINES = 120  # a function longer than this does several things: give each its name


def test_no_function_is_over_120_lines():
    long = {}
    for name, path in MODULES.items():
        for n in ast.walk(ast.parse(path.read_text())):
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.end_lineno - n.lineno + 1 > MAX_FUNCTION_LINES:
                long[f"{name}.{n.name}"] = n.end_lineno - n.lineno + 1
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines: {long}"


def test_every_demoforge_import_resolves_statically_in_the_checkout():
    """What mypy, pyright and an editor's go-to-definition see: mypy's own module finder, on the checkout
    as a source root, finds the file of every ``demoforge.*`` module that the package, the tests and the
    scripts import (no run-time search-path hook: demoforge/lib, /tasks, /flows, /schemas are folders)."""
    from mypy.modulefinder import FindModuleCache, ModuleNotFoundReason, SearchPaths
    from mypy.options import Options

    names = set()
    for folder in ("demoforge", "tests", "scripts"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for n in _import_nodes(ast.parse(path.read_text())):
                if isinstance(n, ast.Import):
                    names |= {a.name for a in n.names if a.name.split(".")[0] == "demoforge"}
                elif n.module and not n.level and n.module.split(".")[0] == "demoforge":
                    names.add(n.module)
    finder = FindModuleCache(SearchPaths((str(ROOT),), (), (), ()), None, Options())
    unresolved = sorted(m for m in names if isinstance(finder.find_module(m), ModuleNotFoundReason))
    assert len(names) > 100 and unresolved == []
