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


def _imports(name: str, path: Path, module_level_only: bool) -> set[str]:
    """Modules of the package that ``name`` imports (at module level, or anywhere)."""
    tree = ast.parse(path.read_text())
    nodes = tree.body if module_level_only else list(ast.walk(tree))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for n in nodes:
        if isinstance(n, ast.Import):
            targets = [a.name for a in n.names]
        elif isinstance(n, ast.ImportFrom):
            base = n.module or ""
            if n.level:
                up = package.split(".")[: len(package.split(".")) - (n.level - 1)]
                base = ".".join(up + ([n.module] if n.module else []))
            # `from a.b import c`: module a.b.c when c is one, else a.b
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in n.names]
        else:
            continue
        out |= {t for t in targets if t in MODULES and t != name}
    return out


def test_no_import_cycles():
    edges = {m: _imports(m, p, module_level_only=True) for m, p in MODULES.items()}
    index, low, stack, on, cycles = {}, {}, [], set(), []

    def visit(v):  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges[v]:
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
    assert cycles == []


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
