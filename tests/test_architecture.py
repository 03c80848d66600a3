"""The layers of docs/architecture.md, checked on the source (tests/support/import_graph.py reads it): no import
loop between modules or rooms (imports inside functions count), no private name taken from another room,
no import back up a layer, Prefect stages only in tasks/, no module over 600 lines nor function over 120,
every demoforge import resolvable by static tools; and where the tests live: every module has its mirrored test
file (tests/<path>/test_<module>.py) or an entry in tests/support/tested_through.py that the table's rules hold for."""

import ast
import functools
from pathlib import Path

from tests.support.import_graph import cycles, find_modules, import_nodes, imported, room
from tests.support.mirror import mirrored_test
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


# ------------------------------------------------------------------------------------------ where the tests live
# docs/architecture.md, "Tests": a module's tests are in tests/<path>/test_<module>.py (tests/support/mirror.py), or
# it has an entry in tests/support/tested_through.py saying which test covers it, or why none does.

# test files of the suite or the checkout as a whole (no module of their own), and the folders of shared code
SUITE_FILES = {
    "tests/test_architecture.py": "these rules, on the source",
    "tests/test_packaging.py": "the wheel, installed outside the checkout",
    "tests/test_fail_on_skip.py": "the suite's own hooks (tests/conftest.py)",
}
NOT_MIRRORED = ("tests/support/", "tests/end_to_end/")  # shared helpers; whole pipelines across several commands


def _test_files() -> list[str]:
    return sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "tests").rglob("test_*.py"))


def test_every_module_has_its_mirrored_test_file_or_an_entry_in_the_tested_through_table():
    from tests.support.mirror import layout
    from tests.support.tested_through import TESTED_THROUGH

    mirrored = layout(ROOT)
    neither = [f"{m} (tests/support/mirror.py: {mirrored_test(m, p)})" for m, p in MODULES.items()
               if m not in mirrored and m not in TESTED_THROUGH]
    assert neither == [], "give each a test file or an entry in tests/support/tested_through.py"
    both = sorted(set(mirrored) & set(TESTED_THROUGH))
    assert both == [], f"these have their own test file now: remove their entries from the table: {both}"
    assert sorted(set(TESTED_THROUGH) - set(MODULES)) == []  # no entry for a module that is gone


@functools.cache
def _named(name: str) -> frozenset[str]:
    """Modules a module loads by name: string constants "demoforge.x.y" or "demoforge.x.y:attr" (lazy registry
    entries, demoforge.lib.registry)."""
    consts = (n.value for n in ast.walk(ast.parse(MODULES[name].read_text()))
              if isinstance(n, ast.Constant) and isinstance(n.value, str))
    return frozenset(c.split(":")[0] for c in consts if c.split(":")[0] in MODULES)


def _reaches(start: set[str], module: str) -> bool:
    """Whether ``module`` is among the package's modules that ``start`` import (or load by name), directly or not."""
    seen, todo = set(start), list(start)
    while todo:
        for t in _imports(m := todo.pop(), MODULES[m]) | _named(m):
            if t not in seen:
                seen.add(t)
                todo.append(t)
    return module in seen


def test_the_tested_through_table_names_test_files_that_import_what_they_cover():
    from tests.support.mirror import direct_imports
    from tests.support.tested_through import TESTED_THROUGH

    wrong = []
    for m, e in TESTED_THROUGH.items():
        if not e.why.strip():
            wrong.append(f"{m}: no reason")
        if e.test is not None:
            if not (ROOT / e.test).is_file():
                wrong.append(f"{m}: {e.test} does not exist")
            elif m not in direct_imports(ROOT / e.test, MODULES):
                wrong.append(f"{m}: {e.test} does not import it by name")
        elif e.reached_by is not None:
            if not (ROOT / e.reached_by).is_file():
                wrong.append(f"{m}: {e.reached_by} does not exist")
            elif not _reaches(direct_imports(ROOT / e.reached_by, MODULES), m):
                wrong.append(f"{m}: nothing {e.reached_by} imports imports it")
        elif e.exempt and any(isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
                              for n in ast.parse(MODULES[m].read_text()).body):
            wrong.append(f"{m}: exempt, but it defines functions or classes of its own")
    assert wrong == []


def test_every_test_file_is_named_after_a_module_of_the_folder_it_mirrors():
    """tests/a/b/test_c.py or test_c_<topic>.py tests demoforge.a.b.c (a module of demoforge/a/b/, or the package
    demoforge/a/b itself when c is b); the suite's own files and the shared and end-to-end folders excepted."""
    stray = []
    for f in _test_files():
        if f in SUITE_FILES or f.startswith(NOT_MIRRORED):
            continue
        folder = f.split("/")[1:-1]
        package = ".".join(["demoforge", *folder])
        stem = f.rsplit("/", 1)[-1][len("test_"):-len(".py")]
        names = {m.rsplit(".", 1)[-1] for m in MODULES if m.rpartition(".")[0] == package}
        names |= {folder[-1] if folder else "demoforge"} if package in MODULES else set()
        if not any(stem == n or stem.startswith(n + "_") for n in names):
            stray.append(f)
    assert stray == [], "name a test file after the module it tests (tests/support/mirror.py)"
