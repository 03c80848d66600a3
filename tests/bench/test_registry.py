"""The benchmarks' registry (demoforge.bench.registry): the command's help names every stage, and each stage's
cases live in a module of their own (run.py holds none)."""

from demoforge.bench.registry import CASE_FACTORIES
from tests.support.paths import REPO_ROOT


def test_the_help_names_every_registered_stage():
    from demoforge.cli.benchmarks import STAGES

    assert sorted(STAGES) == sorted(CASE_FACTORIES)
    assert "llm" in CASE_FACTORIES


def test_every_stage_has_its_cases_in_a_module_of_its_own_and_run_py_holds_none():
    import ast

    from demoforge.bench.registry import CASE_MODULES

    bench = REPO_ROOT / "demoforge" / "bench"
    for stage, module in CASE_MODULES.items():
        tree = ast.parse((bench / f"{module}.py").read_text())
        assert any(isinstance(n, ast.FunctionDef) and n.name == "cases" for n in tree.body), (stage, module)
    calls = [n for n in ast.walk(ast.parse((bench / "run.py").read_text()))
             if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "BenchCase"]
    assert calls == []
