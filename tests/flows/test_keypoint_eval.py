"""The evaluate-keypoints flow on a fake ARCTIC tree, on synthetic takes, and the SQL tables vs lib."""

import numpy as np
import pytest
from typer.testing import CliRunner

from demoforge.cli import app
from demoforge.flows.keypoint_eval import evaluate_keypoints
from tests.support.keypoint_tables import table1, table2
from demoforge.schemas.catalog import query
from tests.support.arctic_fixture import build_arctic_tree
from demoforge.lib import SHARED_DATA
from tests.support.mediapipe_model import require_mediapipe_model


def test_arctic_flow_writes_the_thesis_tables(prefect_api, warehouse, tmp_path):
    root = tmp_path / "arctic"
    build_arctic_tree(root, subject="s01", seqs=("box_grab_01", "phone_use_01"), T=40)
    # the command's main path: its options (takes, subject, stride) reach the flow
    r = CliRunner().invoke(app, ["evaluate-keypoints", "--dataset", "arctic", "--arctic-root", str(root), "--take",
                                 "box_grab_01", "--take", "phone_use_01", "--subject", "s01", "--stride", "2"])
    assert r.exit_code == 0, r.output
    rows = query("SELECT * FROM keypoint_metrics ORDER BY take, hand", warehouse).to_pylist()
    assert [(x["take"], x["n_frames"]) for x in rows] == [("box_grab_01", 10)] * 2 + [("phone_use_01", 10)] * 2
    assert "mpjpe" in r.stdout                      # report_table1, printed
    assert {r["size_group"] for r in rows} == {"big", "small"}
    assert all(r["anchor_depth_source"] == "ground_truth" and r["detector"] == "simulated" for r in rows)
    for r in rows:
        assert r["mpjpe_m"] > 0.3 and r["mpjpe_aligned_m"] < 0.05 and r["pa_mpjpe_m"] < r["mpjpe_aligned_m"] + 1e-9

    # the SQL view and the library's table builder agree (frame-weighted means)
    sql1 = {(r["hand"], r["aligned"]): r for r in query("SELECT * FROM report_table1", warehouse).to_pylist()}
    for r in table1(rows):
        s = sql1[(r["hand"], r["aligned"])]
        assert s["mpjpe_m"] == pytest.approx(r["mpjpe_m"], abs=1e-4)
        assert s["pa_mpjpe_m"] == pytest.approx(r["pa_mpjpe_m"], abs=1e-4)
    sql2 = {r["hand"]: r for r in query("SELECT * FROM report_table2", warehouse).to_pylist()}
    for r in table2(rows):
        assert sql2[r["hand"]]["pck05"] == pytest.approx(r["pck05"], abs=1e-4)
    app_b = query("SELECT * FROM report_appendix_b", warehouse).to_pylist()
    assert [r["take"] for r in app_b] == ["box_grab_01", "phone_use_01"]
    groups = query("SELECT size_group FROM report_big_vs_small ORDER BY size_group", warehouse).column(0).to_pylist()
    assert groups == ["big", "small"]


def test_arctic_errors_name_what_is_missing(warehouse, tmp_path):
    r = CliRunner().invoke(app, ["evaluate-keypoints", "--dataset", "arctic", "--arctic-root", str(tmp_path)])
    assert r.exit_code == 2 and "not found under" in r.stderr and "download ARCTIC" in r.stderr
    r = CliRunner().invoke(app, ["evaluate-keypoints", "--dataset", "arctic"], env={"DEMOFORGE_ARCTIC_ROOT": ""})
    assert r.exit_code == 2 and "arctic-root" in r.stderr


@pytest.mark.skipif(not (SHARED_DATA / "real_hands").is_dir(), reason="../shared/data/real_hands not present: the real "
                    "hand photos come with the shared data folder (../shared/data beside the checkout)")
def test_real_photo_table(prefect_api, warehouse):
    require_mediapipe_model()
    evaluate_keypoints(str(warehouse), dataset="real_photos")
    rows = {r["dataset"]: r for r in query("SELECT * FROM report_real_photos", warehouse).to_pylist()}
    assert set(rows) == {"freihand", "onehand10k", "panoptic", "coco_wholebody", "all"}
    assert rows["all"]["hands"] == 26 and rows["all"]["detected"] >= 11
    assert rows["all"]["pck20"] >= 0.85
