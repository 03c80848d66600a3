"""The DuckDB catalog and `demoforge sql`: read-only, one-line errors with exit code 2."""

import json
import subprocess
import sys
from pathlib import Path

import duckdb
import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from demoforge.cli import app
from demoforge.schemas.catalog import (
    CATALOG_FILE, QueryRefused, build_catalog, catalog_is_current, check_read_only, query,
)
from demoforge.schemas.core import write_table

from tests.support.poses_table import pose_rows  # registers the _test_poses table
from tests.support.paths import REPO_ROOT

runner = CliRunner()


def sql(*args, **kw):
    return runner.invoke(app, ["sql", *args], **kw)


def test_select_one_works_on_an_empty_warehouse(warehouse):
    r = sql("SELECT 1 AS one")
    assert r.exit_code == 0, r.output
    assert "one" in r.stdout and "1" in r.stdout
    assert (warehouse / CATALOG_FILE).exists()


@pytest.mark.parametrize(
    "statement",
    [
        "DROP VIEW benchmarks",
        "INSERT INTO benchmarks SELECT * FROM benchmarks",
        "COPY (SELECT 1) TO 'out.csv'",
        "CREATE TABLE x AS SELECT 1",
        "ATTACH 'other.duckdb'",
        "SELECT 1; DROP VIEW benchmarks",
        "SET threads = 1",
    ],
)
def test_writes_are_refused_with_one_line_and_exit_2(warehouse, statement, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = sql(statement)
    assert r.exit_code == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ")
    # refused by demoforge's own guard, before any connection: DuckDB's read-only connection and
    # the confinement would refuse most of these too, so their message must not be enough here
    assert "`demoforge sql`" in lines[0], lines[0]
    with pytest.raises(QueryRefused, match="`demoforge sql`"):
        check_read_only(statement)
    assert not (tmp_path / "out.csv").exists() and not (tmp_path / "other.duckdb").exists()
    assert query("SELECT count(*) AS n FROM benchmarks").column("n")[0].as_py() == 0


@pytest.mark.parametrize(
    "statement",
    [
        "SELECT * FROM read_text('/etc/hostname')",
        "SELECT * FROM read_csv('/etc/passwd')",
        "SELECT * FROM read_blob('/etc/hostname')",
        "SELECT * FROM glob('/etc/*')",
        "SELECT * FROM read_text('{wh}/_prefect/secret.txt')",  # inside the warehouse, but not a table
        "SELECT * FROM read_text('{wh}/benchmarks/../_prefect/secret.txt')",
        "SELECT * FROM read_parquet('{outside}/t.parquet')",
        "SELECT * FROM read_parquet('https://127.0.0.1:9/t.parquet')",
    ],
)
def test_queries_cannot_read_outside_the_warehouse_tables(warehouse, statement, tmp_path):
    import pyarrow as pa

    (warehouse / "_prefect").mkdir()
    (warehouse / "_prefect" / "secret.txt").write_text("s3cr3t")
    (tmp_path / "outside").mkdir()
    pq.write_table(pa.table({"s3cr3t": [1]}), tmp_path / "outside" / "t.parquet")
    r = sql(statement.format(wh=warehouse, outside=tmp_path / "outside"))
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "refused: queries read only the warehouse's tables" in lines[0], lines
    assert "s3cr3t" not in r.output


@pytest.mark.parametrize("statement", ["SET enable_external_access = true", "RESET lock_configuration",
                                       "SET allowed_directories = ['/']"])
def test_confinement_cannot_be_lifted_from_a_query(warehouse, statement):
    from demoforge.schemas.catalog import confined_connection

    build_catalog(warehouse)
    con = confined_connection(warehouse)  # below the guard: the lock itself must hold
    try:
        with pytest.raises(duckdb.Error, match="locked"):
            con.execute(statement)
        with pytest.raises(duckdb.PermissionException):
            con.execute("SELECT * FROM read_text('/etc/hostname')")
    finally:
        con.close()


def test_every_readme_query_runs(warehouse):
    """Each `demoforge sql "..."` example in README.md and docs/ binds and runs through the confined connection."""
    import re

    repo = REPO_ROOT
    manual = "\n".join(p.read_text() for p in [repo / "README.md", *sorted((repo / "docs").glob("*.md"))])
    examples = [e for e in re.findall(r'demoforge sql "([^"]+)"', manual) if "..." not in e]  # not placeholders
    assert len(examples) >= 10
    write_table("_test_poses", pose_rows(2, "a"), warehouse)  # one table with files, so a view reads Parquet
    for example in examples:
        query(" ".join(example.split()), warehouse)
    assert query("SELECT count(*) AS n FROM _test_poses", warehouse).column("n")[0].as_py() == 2


def test_malformed_and_failing_queries_give_exit_2(warehouse):
    for bad in ["SELEC 1", "SELECT * FROM no_such_table", "", "SELECT 1/'a'"]:
        r = sql(bad)
        assert r.exit_code == 2, (bad, r.output)
        assert len(r.stderr.strip().splitlines()) == 1


def test_views_follow_new_files_and_keep_fixed_array_types(warehouse):
    write_table("_test_poses", pose_rows(3, "a"), warehouse)
    t = query("SELECT take, frame, joints FROM _test_poses ORDER BY frame")
    assert t.num_rows == 3
    assert str(query("SELECT typeof(joints) AS t FROM _test_poses LIMIT 1").column("t")[0]) == "DOUBLE[3][21]"
    write_table("_test_poses", pose_rows(2, "b"), warehouse)  # a new partition: catalog goes stale, rebuilt
    assert not catalog_is_current(warehouse)
    n = query("SELECT count(*) AS n FROM _test_poses").column("n")[0].as_py()
    assert n == 5 and catalog_is_current(warehouse)


def test_catalog_holds_views_only(warehouse):
    write_table("_test_poses", pose_rows(), warehouse)
    build_catalog(warehouse)
    con = duckdb.connect(str(warehouse / CATALOG_FILE), read_only=True)
    try:
        assert con.execute("SELECT count(*) FROM duckdb_tables()").fetchone()[0] == 0
        views = {r[0] for r in con.execute("SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()}
    finally:
        con.close()
    assert {"benchmarks", "_test_poses", "_catalog"} <= views


def test_output_formats(warehouse, tmp_path):
    write_table("_test_poses", pose_rows(2, "a"), warehouse)
    r = sql("SELECT frame, joints FROM _test_poses ORDER BY frame", "--format", "json")
    rows = [json.loads(l) for l in r.stdout.splitlines()]
    assert [x["frame"] for x in rows] == [0, 1] and np.array(rows[0]["joints"]).shape == (21, 3)
    out = tmp_path / "q.csv"
    r = sql("SELECT frame, joints FROM _test_poses ORDER BY frame", "--format", "csv", "--output", str(out))
    assert r.exit_code == 0
    lines = out.read_text().splitlines()
    assert lines[0] == '"frame","joints"' and len(lines) == 3
    pq_out = tmp_path / "q.parquet"
    r = sql("SELECT frame FROM _test_poses", "--format", "parquet", "--output", str(pq_out))
    assert r.exit_code == 0 and pq.read_table(pq_out).num_rows == 2
    r = sql("SELECT 1", "--format", "parquet")
    assert r.exit_code == 2 and "--output" in r.stderr


def test_warehouse_option_overrides_environment(warehouse, tmp_path):
    other = tmp_path / "other"
    write_table("_test_poses", pose_rows(4, "z"), other)
    r = runner.invoke(app, ["--warehouse", str(other), "sql", "SELECT count(*) AS n FROM _test_poses", "-f", "csv"])
    assert r.exit_code == 0 and r.stdout.splitlines()[1] == "4"
    assert query("SELECT count(*) AS n FROM _test_poses").column("n")[0].as_py() == 0  # env warehouse untouched


def test_console_script_exit_codes(warehouse):
    exe = Path(sys.executable).parent / "demoforge"
    ok = subprocess.run([str(exe), "sql", "SELECT 42 AS answer", "-f", "csv"], capture_output=True, text=True)
    assert ok.returncode == 0 and ok.stdout.splitlines() == ["\"answer\"", "42"]
    bad = subprocess.run([str(exe), "sql", "DROP VIEW benchmarks"], capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1
    helped = subprocess.run([str(exe), "--help"], capture_output=True, text=True)
    for command in ("sql", "catalog", "tables", "bench"):
        assert command in helped.stdout


def test_query_refused_is_raised_for_library_callers(warehouse):
    with pytest.raises(QueryRefused):
        query("DELETE FROM benchmarks")


_SIM_V1_COLUMNS = {"task": "string", "take": "string", "chunk": "int32", "episode_id": "int64", "kind": "string",
                   "success": "bool", "failure": "string", "detail": "string", "predicate_ok": "bool",
                   "predicate_detail": "string", "duration_s": "float64", "physics_steps": "int64", "wall_s": "float64"}


def _old_sim_file(root: Path, version: int, task: str, chunk: int, ids: list[int], selection: str = "all") -> Path:
    """A sim_results file as an older contract wrote it: version 1 (no selection column, task=/take=/chunk=)
    or version 2 (selection, task=/take=/selection=/chunk=; neither has a robot)."""
    import pyarrow as pa

    columns = dict(_SIM_V1_COLUMNS)
    if version == 2:
        columns = {**dict(list(columns.items())[:2]), "selection": "string", **dict(list(columns.items())[2:])}
    n = len(ids)
    values = {"task": [task] * n, "take": ["t0"] * n, "selection": [selection] * n, "chunk": [chunk] * n,
              "episode_id": ids, "kind": ["translated"] * n, "success": [True] * n, "failure": [""] * n,
              "detail": ["ok"] * n, "predicate_ok": [True] * n, "predicate_detail": [""] * n, "duration_s": [1.0] * n,
              "physics_steps": [480] * n, "wall_s": [0.1] * n}
    schema = pa.schema([(k, getattr(pa, v)() if v != "bool" else pa.bool_()) for k, v in columns.items()],
                       metadata={b"demoforge.schema_version": str(version).encode()})
    t = pa.table({k: pa.array(values[k], schema.field(k).type) for k in columns}, schema=schema)
    sel = f"selection={selection}/" if version == 2 else ""
    path = root / "sim_results" / f"task={task}" / "take=t0" / f"{sel}chunk={chunk}" / "data.parquet"
    path.parent.mkdir(parents=True)
    pq.write_table(t, path)
    return path


def test_version_1_sim_results_are_moved_to_the_legacy_selection_without_losing_rows(warehouse):
    from demoforge.schemas.core import migrate_warehouse, read_table

    old = [_old_sim_file(warehouse, 1, "pouring", 0, [0, 5, 9]), _old_sim_file(warehouse, 1, "pouring", 1, [12, 13])]
    rows = query("SELECT selection, robot, gripper, chunk, episode_id FROM sim_results ORDER BY episode_id",
                 warehouse).to_pylist()
    assert rows == [{"selection": "legacy", "robot": "grippers", "gripper": "2f140", "chunk": c, "episode_id": e}
                    for c, e in [(0, 0), (0, 5), (0, 9), (1, 12), (1, 13)]]
    assert not any(p.exists() or p.parent.exists() for p in old)
    assert read_table("sim_results", warehouse).num_rows == 5  # the reader finds them in the new layout
    assert migrate_warehouse(warehouse) == {}  # nothing left to move

    # a crash between writing the copy and removing the old file: the next migration finishes it
    again = _old_sim_file(warehouse, 1, "pouring", 1, [12, 13])
    assert migrate_warehouse(warehouse) == {"sim_results": 1} and not again.exists()
    assert read_table("sim_results", warehouse).num_rows == 5
    # an old process still running wrote chunk 1 again, with other episodes: both files' rows are kept
    _old_sim_file(warehouse, 1, "pouring", 1, [13, 20, 21])
    assert migrate_warehouse(warehouse) == {"sim_results": 1}
    rows = query("SELECT chunk, episode_id FROM sim_results WHERE chunk = 1 ORDER BY 2", warehouse).to_pylist()
    assert [r["episode_id"] for r in rows] == [12, 13, 20, 21]


def test_version_2_sim_results_become_the_grippers_rows(warehouse):
    """Results written before robots had names were the floating grippers': they keep their selection
    and every value, gain robot = grippers / gripper = 2f140 and null arm columns, and sit beside the
    arms' rows of the same episodes."""
    from demoforge.schemas.core import migrate_warehouse, read_table, table_files

    old = _old_sim_file(warehouse, 2, "pouring", 0, [0, 4], selection="sample-2-seed0")
    arms = {"task": ["pouring"], "take": ["t0"], "robot": ["aloha"], "gripper": ["aloha"],
            "selection": ["sample-2-seed0"], "chunk": [0], "episode_id": [4], "kind": ["translated"],
            "success": [False], "failure": ["unreachable"], "detail": ["arm 0 ends 30 mm ..."],
            "predicate_ok": [None], "predicate_detail": [""], "reachable": [False], "ik_position_error_m": [0.03],
            "ik_rotation_error_deg": [2.0], "time_scale": [1.1], "duration_s": [0.5], "physics_steps": [240], "wall_s": [0.2]}
    write_table("sim_results", arms, warehouse)
    rows = query("SELECT robot, gripper, selection, episode_id, success, reachable, ik_position_error_m "
                 "FROM sim_outcomes ORDER BY robot, episode_id", warehouse).to_pylist()
    assert rows == [{"robot": "aloha", "gripper": "aloha", "selection": "sample-2-seed0", "episode_id": 4,
                     "success": False, "reachable": False, "ik_position_error_m": 0.03}] + [
        {"robot": "grippers", "gripper": "2f140", "selection": "sample-2-seed0", "episode_id": e, "success": True,
         "reachable": None, "ik_position_error_m": None} for e in (0, 4)]
    assert not old.exists() and migrate_warehouse(warehouse) == {}
    assert len(table_files("sim_results", warehouse, robot="grippers", gripper="2f140")) == 1
    assert read_table("sim_results", warehouse).num_rows == 3


def test_sim_outcomes_keeps_one_row_per_episode_preferring_the_whole_database_run(warehouse):
    base = {"task": "pouring", "take": "t0", "robot": "grippers", "gripper": "2f140", "kind": "translated",
            "failure": "", "detail": "", "predicate_ok": True, "predicate_detail": "", "reachable": None,
            "ik_position_error_m": None, "ik_rotation_error_deg": None, "time_scale": None, "duration_s": 1.0, "physics_steps": 480,
            "wall_s": 0.1}
    rows = [dict(base, selection="sample-2-seed0", chunk=0, episode_id=0, success=False),
            dict(base, selection="sample-2-seed0", chunk=0, episode_id=7, success=False),
            dict(base, selection="all", chunk=0, episode_id=0, success=True),
            dict(base, selection="all", chunk=0, episode_id=1, success=True)]
    for sel in ("sample-2-seed0", "all"):
        part = [r for r in rows if r["selection"] == sel]
        write_table("sim_results", {k: [r[k] for r in part] for k in part[0]}, warehouse)
    got = query("SELECT episode_id, selection, success FROM sim_outcomes ORDER BY 1", warehouse).to_pylist()
    assert got == [{"episode_id": 0, "selection": "all", "success": True},
                   {"episode_id": 1, "selection": "all", "success": True},
                   {"episode_id": 7, "selection": "sample-2-seed0", "success": False}]
    assert query("SELECT sum(episodes) AS n FROM report_sim", warehouse).column("n")[0].as_py() == 3


def test_values_are_passed_as_parameters_not_spliced(warehouse):
    """A value with a quote is data: it cannot end the string and change the statement."""
    write_table("_test_poses", pose_rows(3, "a"), warehouse)
    n = lambda take: query("SELECT count(*) AS n FROM _test_poses WHERE take = ?", warehouse, [take]).column("n")[0].as_py()
    assert n("a") == 3
    assert n("a' OR '1'='1") == 0


def _spliced_values(path: Path) -> list[str]:
    """f-strings passed to query() that put a value inside quotes or after `=`/`IN (` (a splice)."""
    import ast

    bad = []
    for node in ast.walk(ast.parse(path.read_text())):
        if not (isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) == "query"):
            continue
        for s in (n for n in ast.walk(node.args[0]) if isinstance(n, ast.JoinedStr)) if node.args else ():
            for before, part in zip(s.values, s.values[1:]):
                if (isinstance(part, ast.FormattedValue) and isinstance(before, ast.Constant)
                        and before.value.rstrip().endswith(("'", "=", "IN ("))
                        and getattr(getattr(part.value, "func", None), "id", None) != "placeholders"):
                    bad.append(f"{path.name}:{node.lineno}")
    return bad


def test_no_query_splices_a_value_into_its_sql():
    root = REPO_ROOT
    files = [p for d in ("demoforge", "scripts") for p in sorted((root / d).rglob("*.py"))]
    assert len(files) > 50
    assert [b for f in files for b in _spliced_values(f)] == []


def test_version_3_sim_results_gain_a_null_time_scale_in_place(warehouse):
    """Results written before the arms were retimed (no `time_scale`) keep their file, rows and values; the
    column is null (not measured), and the migration runs once."""
    from demoforge.schemas.core import migrate_warehouse, read_table, write_table

    row = {"task": ["pouring"], "take": ["t0"], "robot": ["aloha"], "gripper": ["2f140"], "selection": ["all"],
           "chunk": [0], "episode_id": [3], "kind": ["translated"], "success": [False], "failure": ["joint_limit"],
           "detail": ["speed"], "predicate_ok": [None], "predicate_detail": [""], "reachable": [False],
           "ik_position_error_m": [0.02], "ik_rotation_error_deg": [15.0], "time_scale": [None], "duration_s": [0.2],
           "physics_steps": [100], "wall_s": [0.1]}
    (written,) = write_table("sim_results", row, warehouse)
    path = Path(written.path)
    t = pq.read_table(path).drop(["time_scale"])
    pq.write_table(t.replace_schema_metadata({**t.schema.metadata, b"demoforge.schema_version": b"3"}), path)
    assert migrate_warehouse(warehouse) == {"sim_results": 1} and path.exists()
    got = read_table("sim_results", warehouse).to_pylist()
    assert len(got) == 1 and got[0]["time_scale"] is None and got[0]["failure"] == "joint_limit"
    assert got[0]["ik_rotation_error_deg"] == 15.0 and migrate_warehouse(warehouse) == {}
