"""Issue 19 point 5: a take ingested with the simulated detector and with MediaPipe keeps both ingests
side by side (the second detector's rows under `detector=<name>/`, the first's paths and cache keys as
they were), and the side-by-side tables (ingest accuracy, keypoint metrics, the robot executing each
ingested demonstration) hold one set of rows per detector, each with its own values."""

from pathlib import Path

import pyarrow as pa
import pytest
from prefect import flow

from demoforge.schemas.core import (
    ALL_VARIANTS, Column, SchemaError, file_sha256, read_table, table, table_files, write_table,
)
from demoforge.tasks.common import Manifest, run_stage, stage_task
from tests.support.mediapipe_model import require_mediapipe_model

table("_test_variant", 1, "per-detector rows of one partition (variant test)", [
    Column("take", pa.string(), "take"),
    Column("detector", pa.string(), "detector"),
    Column("value", pa.float64(), "a value"),
], partition_by=("take",))


def _rows(detector: str, value: float) -> dict:
    return {"take": ["t1", "t1"], "detector": [detector] * 2, "value": [value, value + 1]}


def test_a_variant_is_kept_beside_the_default_rows_and_sql_sees_both(tmp_path):
    from demoforge.schemas.catalog import query

    wh = tmp_path / "wh"
    default = write_table("_test_variant", _rows("simulated", 1.0), wh)
    other = write_table("_test_variant", _rows("mediapipe", 10.0), wh, {"detector": "mediapipe"})
    # the default rows keep their path; the variant's lie under detector=mediapipe/
    assert Path(default[0].path) == wh / "_test_variant" / "take=t1" / "data.parquet"
    assert Path(other[0].path) == wh / "_test_variant" / "detector=mediapipe" / "take=t1" / "data.parquet"
    assert file_sha256(default[0].path) == default[0].content_hash  # not overwritten by the variant
    assert read_table("_test_variant", wh, take="t1").column("detector").to_pylist() == ["simulated"] * 2
    assert read_table("_test_variant", wh, variant={"detector": "mediapipe"}, take="t1").column("value").to_pylist() == [10.0, 11.0]
    assert len(table_files("_test_variant", wh)) == 1
    assert len(table_files("_test_variant", wh, ALL_VARIANTS)) == 2
    assert len(table_files("_test_variant", wh, ALL_VARIANTS, take="t1")) == 2
    t = query("SELECT detector, sum(value) AS s FROM _test_variant GROUP BY detector ORDER BY detector", wh)
    assert t.to_pylist() == [{"detector": "mediapipe", "s": 21.0}, {"detector": "simulated", "s": 3.0}]


def test_a_variant_refuses_rows_of_another_value_and_unknown_keys(tmp_path):
    with pytest.raises(SchemaError, match="variant detector=mediapipe"):
        write_table("_test_variant", _rows("simulated", 1.0), tmp_path, {"detector": "mediapipe"})
    with pytest.raises(SchemaError, match="variant key 'take'"):  # a partition column is no variant
        write_table("_test_variant", _rows("simulated", 1.0), tmp_path, {"take": "t1"})
    with pytest.raises(SchemaError, match="may only contain"):
        write_table("_test_variant", _rows("../x", 1.0), tmp_path, {"detector": "../x"})


CALLS = {"n": 0}


def _stage_before(warehouse: str, n: int) -> Manifest:
    CALLS["n"] += 1
    return Manifest.from_written("_test_variant", write_table("_test_variant", _rows("simulated", float(n)), warehouse))


def _stage_after(warehouse: str, n: int, variant: dict | None = None) -> Manifest:
    CALLS["n"] += 1
    det = (variant or {}).get("detector", "simulated")
    return Manifest.from_written("_test_variant", write_table("_test_variant", _rows(det, float(n)), warehouse, variant))


before = stage_task(name="variant_stage", version="1")(_stage_before)
after = stage_task(name="variant_stage", version="1", key_optional=("variant",))(_stage_after)


@flow(name="variant-keys")
def _variant_flow(warehouse: str, new_code: bool, variant: dict | None = None) -> Manifest:
    if not new_code:
        return run_stage(before, warehouse, warehouse=warehouse, n=3)
    return run_stage(after, warehouse, warehouse=warehouse, n=3, **({"variant": variant} if variant else {}))


def test_a_stage_that_gains_a_variant_keeps_its_cache_keys(prefect_api, tmp_path):
    wh = str(tmp_path / "wh")
    CALLS["n"] = 0
    first = _variant_flow(wh, new_code=False)
    assert CALLS["n"] == 1
    again = _variant_flow(wh, new_code=True)  # the stage has a `variant` parameter now, left at None
    assert CALLS["n"] == 1 and again.content_hash == first.content_hash
    mp = _variant_flow(wh, new_code=True, variant={"detector": "mediapipe"})  # a variant is a new key
    assert CALLS["n"] == 2 and "detector=mediapipe" in mp.path


def test_a_take_ingested_with_both_detectors_has_rows_for_both(prefect_api, ingested_warehouse, trash_take):
    """The default trash_in_bin take (already ingested with the simulated detector) ingested side by side
    with MediaPipe: the simulated rows stay as they were (same files), every side-by-side table holds rows
    of both detectors with the right labels, and the values differ between them."""
    require_mediapipe_model()
    from demoforge.flows.ingest import ingest_side_by_side
    from demoforge.schemas.catalog import query

    wh = str(ingested_warehouse)
    before = {str(f): file_sha256(f) for name in ("hand_keypoints", "aligned_keypoints", "gripper_poses",
                                                    "ingest_metrics", "hand_presence")
              for f in table_files(name, wh)}
    out = ingest_side_by_side(str(trash_take), wh, detectors=["simulated", "mediapipe"])
    assert [d for d, r in out.items() if r["error"]] == [], {d: r["error"] for d, r in out.items()}
    assert {str(f): file_sha256(f) for f in before} == before  # MediaPipe's ingest overwrote nothing
    for name in ("hand_keypoints", "gripper_poses", "ingest_metrics", "hand_presence"):
        t = query(f"SELECT DISTINCT detector FROM {name} ORDER BY detector", wh)
        assert t.column(0).to_pylist() == ["mediapipe", "simulated"], name
        assert read_table(name, wh, variant={"detector": "mediapipe"}).column("detector").unique().to_pylist() == ["mediapipe"]

    acc = {(r["detector"], r["hand"]): r for r in query(
        "SELECT detector, hand, detected_fraction, gripper_position_error_mm, open_close_acc_auto "
        "FROM ingest_metrics", wh).to_pylist()}
    assert sorted(acc) == [("mediapipe", "left"), ("mediapipe", "right"), ("simulated", "left"), ("simulated", "right")]
    for hand in ("left", "right"):
        assert acc[("simulated", hand)]["gripper_position_error_mm"] != acc[("mediapipe", hand)]["gripper_position_error_mm"]
        assert acc[("simulated", hand)]["detected_fraction"] != acc[("mediapipe", hand)]["detected_fraction"]

    kp = query("SELECT detector, hand, mpjpe_m FROM keypoint_metrics WHERE dataset = 'synthetic' "
               "ORDER BY detector, hand", wh).to_pylist()
    assert [(r["detector"], r["hand"]) for r in kp] == [("mediapipe", "left"), ("mediapipe", "right")]
    assert all(r["mpjpe_m"] > 0 for r in kp)

    demos = {r["detector"]: r for r in query("SELECT * FROM ingested_demo_checks", wh).to_pylist()}
    assert sorted(demos) == ["mediapipe", "simulated"]
    assert {r["take"] for r in demos.values()} == {trash_take.name}
    assert demos["simulated"]["status"] == "executed" and demos["simulated"]["valid_left"] == 1.0
    # each detector's own trajectory was executed: MediaPipe's has frames without a pose of its own
    assert demos["mediapipe"]["valid_left"] < 1.0 or demos["mediapipe"]["valid_right"] < 1.0
    assert (demos["mediapipe"]["success"], demos["mediapipe"]["failure"], demos["mediapipe"]["detail"]) != \
        (demos["simulated"]["success"], demos["simulated"]["failure"], demos["simulated"]["detail"])


def _flow_must_not_run(*a, **k):
    raise AssertionError("the main job started")


def test_evaluate_refuses_a_detector_it_does_not_run(warehouse, monkeypatch):
    from typer.testing import CliRunner

    from demoforge.cli import app

    monkeypatch.setattr("demoforge.flows.evaluate.evaluate", _flow_must_not_run)

    r = CliRunner().invoke(app, ["evaluate", "--detector", "simulated", "--detector", "precomputed"])
    assert r.exit_code == 2
    assert r.stderr.strip().splitlines() == [
        "error: --detector 'precomputed' is not one the main job runs; choose from simulated, mediapipe"]


def test_evaluate_stops_when_a_detector_asked_for_cannot_run(warehouse, monkeypatch):
    """Asked for by name, a detector that cannot run here stops the command before any work."""
    from typer.testing import CliRunner

    from demoforge.cli import app

    pytest.importorskip("mediapipe", reason="mediapipe is not installed: the message is then about the package")
    monkeypatch.setattr("demoforge.flows.evaluate.evaluate", _flow_must_not_run)
    monkeypatch.setenv("DEMOFORGE_HAND_LANDMARKER", str(warehouse / "no_such_model.task"))
    r = CliRunner().invoke(app, ["evaluate", "--detector", "mediapipe"])
    assert r.exit_code == 2 and "no_such_model.task" in r.stderr and "fetch_mediapipe_model.py" in r.stderr
    assert not (warehouse / "takes").exists()
