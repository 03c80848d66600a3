"""One settings object: every variable prefixed DEMOFORGE_, old names read for one release with a warning."""

from __future__ import annotations

import ast
from pathlib import Path

from typer.testing import CliRunner

from demoforge.lib.settings import RENAMED, VARIABLES, adopt_old_names, apply_library_defaults, read_settings
from tests.support.paths import REPO_ROOT

ROOT = REPO_ROOT


def test_read_settings_maps_each_variable_and_hides_the_key():
    env = {"DEMOFORGE_WAREHOUSE": "~/wh", "DEMOFORGE_TASK_RUNNER": " Dask ", "DEMOFORGE_LLM_MODEL": "m",
           "DEMOFORGE_GGUF_PATH": "/x/model.gguf", "OPENAI_API_KEY": "sk-secret"}
    s = read_settings(env)
    assert s.warehouse == Path("~/wh").expanduser()
    assert s.task_runner == "dask"
    assert s.llm_model == "m"
    assert s.gguf_path == Path("/x/model.gguf")
    assert s.arctic_root is None and s.dask_workers == "2"
    assert "sk-secret" not in repr(s)
    assert read_settings({}).task_runner == "threads"


def test_old_names_are_copied_once_with_a_warning_and_the_new_name_wins():
    env = {"TRIALS": "7", "SEED": "3", "DEMOFORGE_SEED": "5"}
    warnings: list[str] = []
    found = adopt_old_names(env, warn=warnings.append)
    assert sorted(found) == ["SEED", "TRIALS"]
    assert env["DEMOFORGE_TRIALS"] == "7"
    assert env["DEMOFORGE_SEED"] == "5"
    assert len(warnings) == 2 and all(w.startswith("warning: ") and "\n" not in w for w in warnings)
    assert any("DEMOFORGE_TRIALS" in w for w in warnings)


def test_every_cli_environment_variable_is_prefixed_and_listed():
    names = set()
    for path in (ROOT / "demoforge" / "cli").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.keyword) and node.arg == "envvar" and isinstance(node.value, ast.Constant):
                names.add(node.value.value)
    assert names, "no envvar= found: the scan is broken"
    assert sorted(n for n in names if not n.startswith("DEMOFORGE_")) == []
    assert sorted(names - set(VARIABLES)) == []
    assert set(RENAMED.values()) <= set(VARIABLES)


def test_an_old_name_still_reaches_its_option_through_the_cli(tmp_path):
    from demoforge.cli import app

    # --detector bogus: should the old name not be adopted, the command still stops at once (on the detector)
    r = CliRunner().invoke(app, ["--warehouse", str(tmp_path), "evaluate", "--detector", "bogus"],
                           env={"MIRROR": "sideways", "DEMOFORGE_MIRROR": None})
    # (None: unset during the call and again after it, so the adopted name does not leak into other tests)
    assert r.exit_code == 2, r.output
    assert "--mirror must be both, no or yes, got 'sideways'" in r.output
    assert "MIRROR is deprecated" in r.output and "DEMOFORGE_MIRROR" in r.output


def test_the_new_name_sets_the_option(tmp_path):
    from demoforge.cli import app

    r = CliRunner().invoke(app, ["--warehouse", str(tmp_path), "evaluate", "--detector", "bogus"],
                           env={"DEMOFORGE_MIRROR": "upside"})
    assert r.exit_code == 2 and "got 'upside'" in r.output
    assert "deprecated" not in r.output


def test_prefect_gets_the_library_defaults_whichever_module_imports_it_first():
    """`demoforge bench` imported prefect before demoforge.tasks set its defaults: the temporary server
    ran its telemetry service (a 'database is locked' traceback from send_telemetry_heartbeat) and INFO
    lines. Now the package sets them first; a user's own value wins. In a fresh process: the first import
    decides what Prefect reads."""
    import json
    import os
    import subprocess
    import sys

    code = ("import demoforge.bench.run, json, os\n"
            "from prefect.settings import get_current_settings\n"
            "from prefect._internal.analytics import is_telemetry_enabled\n"
            "s = get_current_settings()\n"
            "print(json.dumps({'server_analytics': s.server.analytics_enabled, 'client_analytics': is_telemetry_enabled(),"
            " 'server_env': os.environ.get('PREFECT_SERVER_ANALYTICS_ENABLED'), 'level': s.logging.level}))")
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_") and k not in ("DO_NOT_TRACK", "CI")}
    got = json.loads(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                    check=True, timeout=120).stdout)
    assert got == {"server_analytics": False, "client_analytics": False, "server_env": "false", "level": "WARNING"}
    mine = {"PREFECT_LOGGING_LEVEL": "INFO"}
    apply_library_defaults(mine)
    assert mine["PREFECT_LOGGING_LEVEL"] == "INFO" and mine["PREFECT_SERVER_ANALYTICS_ENABLED"] == "false"


def test_the_docs_table_lists_every_variable_the_settings_know():
    from demoforge.lib.settings import variables_table

    assert variables_table() in (ROOT / "docs" / "settings.md").read_text()


def test_no_module_but_the_settings_reads_an_environment_variable_except_prefects():
    """One reader: a variable read elsewhere is missing from Settings and from docs/settings.md."""
    import re

    read = re.compile(r"""(?:environ(?:\.get|\.setdefault|\.pop)?\s*[\[(]|getenv\()\s*["']([A-Za-z0-9_]+)["']""")
    found = {}
    for path in (ROOT / "demoforge").rglob("*.py"):  # lib, tasks, flows and schemas are inside it
        if path == ROOT / "demoforge" / "lib" / "settings.py":
            continue
        for name in read.findall(path.read_text()):
            if not name.startswith("PREFECT_"):
                found.setdefault(name, []).append(str(path.relative_to(ROOT)))
    assert found == {}
