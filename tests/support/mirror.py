"""Where a module's tests live (the rule tests/test_architecture.py checks; docs/architecture.md, "Tests"):
``demoforge/a/b/c.py`` -> ``tests/a/b/test_c.py``; a package's own code (``demoforge/a/b/__init__.py``) ->
``tests/a/b/test_b.py``; the package ``demoforge`` itself -> ``tests/test_demoforge.py``. A second file for one
module is ``test_<module>_<topic>.py`` beside the first. Used by tests/test_architecture.py and
scripts/architecture_counts.py, on this checkout or another."""

from __future__ import annotations

import ast
from pathlib import Path

from tests.support.import_graph import find_modules, import_nodes


def mirrored_test(module: str, path: Path) -> str:
    """The test file (relative to the checkout) of ``module``, whose file is ``path``."""
    parts = module.split(".")[1:]
    if path.name == "__init__.py":
        folder, name = parts, (parts[-1] if parts else "demoforge")
    else:
        folder, name = parts[:-1], parts[-1]
    return "/".join(["tests", *folder, f"test_{name}.py"])


def direct_imports(test_file: Path, modules: dict[str, Path]) -> set[str]:
    """The package's modules a test file imports by name (``import demoforge.x.y``, ``from demoforge.x import y``
    (module ``x.y`` if it is one, else ``x``), ``from demoforge.x.y import z``), anywhere in the file."""
    out = set()
    for n in import_nodes(ast.parse(test_file.read_text())):
        if isinstance(n, ast.Import):
            out |= {a.name for a in n.names if a.name in modules}
        elif n.module and not n.level:
            for a in n.names:
                sub = f"{n.module}.{a.name}"
                out.add(sub if sub in modules else n.module)
    return out & set(modules)


def layout(root: Path) -> dict[str, str]:
    """{module: its mirrored test file} for every module of the checkout at ``root`` whose mirrored file exists."""
    return {m: t for m, p in find_modules(root).items() if (root / (t := mirrored_test(m, p))).is_file()}
