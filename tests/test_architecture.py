"""The layers of docs/architecture.md, checked on the source (tests/import_graph.py reads it): no import
loop between modules or rooms (imports inside functions count), no private name taken from another room,
no import back up a layer, Prefect stages only in tasks/, no module over 600 lines nor function over 120,
every demoforge import resolvable by static tools."""

import ast
import functools
from pathlib import Path

from tests.support.import_graph import cycles, find_modules, import_nodes, imported, room
from tests.support.paths import REPO_ROOT

ROOT = REPO_ROOT
MODULES = find_modules(ROOT)


@functools.cache  # every rule reads the same imports: each file is parsed once per session
def _imported(name: str, path: Path) -> list[tuple[str, str | None, int]]:
    return imported(name, path, MODULES)


def _imports(name: str, path: Path) -> set[str]:
    """Modules of the package that ``name`` imports, anywhere in its file."""
    return {t for t, _, _ in _imported(name, path)}


def _module_edges() -> dict[str, set[str]]:
    return {m: _imports(m, p) for m, p in MODULES.items()}


def test_no_import_loop_between_modules_counting_imports_inside_functions():
    assert cycles(_module_edges()) == []


def test_no_import_loop_between_folders():
    edges: dict[str, set[str]] = {}
    for m, targets in _module_edges().items():
        edges.setdefault(room(m), set()).update(room(t) for t in targets if room(t) != room(m))
    assert cycles(edges) == []


def test_no_private_name_is_imported_from_another_room():
    """A leading underscore says "this file's business": another room that needs it needs a public name."""
    leaks = [f"{m}:{line} takes {what} from {t}" for m, p in MODULES.items() for t, what, line in _imported(m, p)
             if what and what.startswith("_") and not what.startswith("__") and room(t) != room(m)]
    assert leaks == []


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "demoforge"


# what each layer may import from the package (anywhere in the file, lazy imports included)
ALLOWED = {
    "lib": {"lib"},
    "envs": {"lib", "envs"},
    "schemas": {"lib", "schemas"},
    "tasks": {"lib", "envs", "schemas", "tasks"},
    "report": {"lib", "schemas", "runtime", "report"},
    "flows": {"lib", "envs", "schemas", "tasks", "flows", "runtime", "report"},
}


# the one exception, and why: a synthetic take carries its ground truth as tables in their contracts
EXCEPTIONS = {("demoforge.lib.synth.take", "schemas")}


def test_no_import_runs_back_up_a_layer():
    wrong = []
    for m, p in MODULES.items():
        layer = _layer(m)
        if layer not in ALLOWED:
            continue
        for t in _imports(m, p):
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
    names = {f.relative_to(ROOT / "demoforge").as_posix() for f in files}
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
            for n in import_nodes(ast.parse(path.read_text())):
                if isinstance(n, ast.Import):
                    names |= {a.name for a in n.names if a.name.split(".")[0] == "demoforge"}
                elif n.module and not n.level and n.module.split(".")[0] == "demoforge":
                    names.add(n.module)
    finder = FindModuleCache(SearchPaths((str(ROOT),), (), (), ()), None, Options())
    unresolved = sorted(m for m in names if isinstance(finder.find_module(m), ModuleNotFoundReason))
    assert len(names) > 100 and unresolved == []
