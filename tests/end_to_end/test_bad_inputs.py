"""The bad-input battery (docs/orchestration.md: Reliability): every kind of broken input a user can hand demoforge.

Each case asserts a clear outcome -- a one-line error (exit code 2) that names the file and the fix,
or a flagged row -- and, where the input is rejected, that the warehouse stays readable and
unchanged. One small synthetic take (8 frames) and one ingested + augmented warehouse are built once
for the module; each test works on copies of them.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from demoforge.cli import app
from demoforge.schemas.catalog import CATALOG_FILE, query
from tests.support.fake_openai import FakeOpenAIServer
from demoforge.lib.trajectories.augmentation.options import AugmentOptions
from demoforge.lib.ingest.options import IngestOptions
from tests.support.paths import REPO_ROOT

PROJECT = REPO_ROOT
N_FRAMES = 8
runner = CliRunner()

# ------------------------------------------------------------------------------------------------
# fixtures and helpers
# ------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def base(tmp_path_factory, prefect_api):
    """A synthetic pouring take (8 frames, PNGs and rgb.mp4), predictions files made from its ground
    truth (both hands / right only / none), and a warehouse where it is ingested and augmented."""
    from demoforge.flows.augment import augment_take_flow
    from demoforge.lib.synth.take import generate_take

    root = tmp_path_factory.mktemp("bad_inputs")
    take = root / "synth_pouring_s0000"
    generate_take("pouring", 0, False, take, max_frames=N_FRAMES, video=True)
    gt = pq.read_table(take / "ground_truth" / "gt_hand_joints.parquet").to_pydict()
    frame, hand = np.array(gt["frame"]), np.array(gt["hand"])
    joints = np.array(gt["joints_camera"], float).reshape(-1, 21, 3)
    preds = {}
    for name, keep in {"both": np.ones(len(hand), bool), "right_only": hand == "right",
                       "none": np.zeros(len(hand), bool)}.items():
        preds[name] = root / f"hands_{name}.npz"
        np.savez(preds[name], frame=frame[keep], hand=hand[keep], joints_cam=joints[keep],
                 confidence=np.ones(int(keep.sum())))
    wh = root / "warehouse"
    augment_take_flow(str(take), str(wh), augment=AugmentOptions(n=20, n_mirrored=10, seed=0), show_progress=False)
    return {"take": take, "warehouse": wh, "preds": preds}


@pytest.fixture()
def wh(base, tmp_path, monkeypatch):
    """A private copy of the base warehouse, made the default one."""
    dst = tmp_path / "warehouse"
    shutil.copytree(base["warehouse"], dst)
    monkeypatch.setenv("DEMOFORGE_WAREHOUSE", str(dst))
    return dst


def take_copy(base, tmp_path, name="synth_pouring_s0000", recorded=False, video=False) -> Path:
    """A copy of the take named ``name``; ``recorded``: without ground truth, as a real recording
    comes; ``video``: frames from rgb.mp4 instead of rgb/."""
    dst = tmp_path / "takes" / name
    shutil.copytree(base["take"], dst)
    meta = json.loads((dst / "take.json").read_text())
    (dst / "take.json").write_text(json.dumps({**meta, "take": name}))  # the take's id in the tables
    if video:
        shutil.rmtree(dst / "rgb")
    else:
        (dst / "rgb.mp4").unlink()
    if recorded:
        shutil.rmtree(dst / "ground_truth")
        (dst / "take.json").unlink(missing_ok=True)
    return dst


def snapshot(root: Path) -> dict[str, str]:
    """Every file of the warehouse and its hash (the catalog holds views only and may be rebuilt)."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and p.name != CATALOG_FILE}


def cli(*args: str):
    return runner.invoke(app, list(args))


def stderr_lines(text: str) -> list[str]:
    """stderr without progress bars (tqdm redraws its line with carriage returns, then blanks it)."""
    lines = [line.split("\r")[-1].strip() for line in text.splitlines()]
    return [line for line in lines if line and "%|" not in line]


def assert_one_line_error(r, *needles: str) -> str:
    assert r.exit_code == 2, (r.exit_code, r.output, r.exception)
    lines = stderr_lines(r.stderr)
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert "Traceback" not in r.output
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def assert_readable(root: Path) -> None:
    n = query("SELECT count(*) AS n FROM frames", root).column("n")[0].as_py()
    assert n >= N_FRAMES
    assert query("SELECT count(*) AS n FROM episodes", root).column("n")[0].as_py() > 0


def rejected(wh: Path, *args: str, needles: tuple[str, ...]) -> str:
    """Run a command that must refuse its input; the warehouse must be unchanged and readable."""
    before = snapshot(wh)
    line = assert_one_line_error(cli(*args), *needles)
    assert snapshot(wh) == before
    assert_readable(wh)
    return line


def frames_of(wh: Path, take: str) -> dict[int, dict]:
    rows = query(f"SELECT frame, status, message FROM frames WHERE take = '{take}'", wh).to_pylist()
    return {r["frame"]: r for r in rows}


# ------------------------------------------------------------------------------------------------
# take files: camera.json, annotations.json
# ------------------------------------------------------------------------------------------------

def test_missing_camera_json(base, wh, tmp_path):
    take = take_copy(base, tmp_path, "no_camera")
    (take / "camera.json").unlink()
    rejected(wh, "ingest", str(take), needles=(str(take / "camera.json"), "missing", "write it"))


@pytest.mark.parametrize("text, needle", [
    ("{not json", "fix the syntax"),
    ('{"K": [[1, 0], [0, 1]], "width": 640, "height": 480, "T_world_camera": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}',
     "'K' must be 3x3"),
    ("[]", "must be a JSON object"),
])
def test_malformed_camera_json(base, wh, tmp_path, text, needle):
    take = take_copy(base, tmp_path, "bad_camera")
    (take / "camera.json").write_text(text)
    rejected(wh, "ingest", str(take), needles=(str(take / "camera.json"), needle))


def test_malformed_annotations_json(base, wh, tmp_path):
    take = take_copy(base, tmp_path, "bad_annotations")
    (take / "annotations.json").write_text('{"object_keypoints_2d": {"frame": 0, "names": ["a"], "uv": [[1]]}')
    rejected(wh, "ingest", str(take), needles=(str(take / "annotations.json"), "fix the syntax"))
    (take / "annotations.json").write_text('{"object_keypoints_2d": {"frame": 0, "names": ["a", "b"], "uv": [[1, 2]]}}')
    rejected(wh, "ingest", str(take), needles=(str(take / "annotations.json"), "2 names but 1 uv points"))


def test_missing_annotations_json_on_a_recorded_take(base, wh, tmp_path):
    """A recorded take has its object keypoints only from annotations.json. Without it the hand stages
    are ingested, the command warns that the take is not annotated yet (exit 0), no object keypoint is
    invented, and augment refuses the take in one line."""
    take = take_copy(base, tmp_path, "no_annotations", recorded=True)
    (take / "annotations.json").unlink()
    r = cli("ingest", str(take), "--task", "pouring", "-d", "precomputed", "--predictions", str(base["preds"]["both"]))
    assert r.exit_code == 0, r.output
    assert "not annotated yet" in r.output and "demoforge annotate" in r.output
    kp = query("SELECT count(*) AS n FROM object_keypoints WHERE take = 'no_annotations'", wh).column("n")[0].as_py()
    assert kp == 0
    r = cli("augment", str(take), "--task", "pouring", "-n", "4", "--mirrored", "2")
    assert_one_line_error(r, "not annotated yet", "demoforge annotate")
    assert_readable(wh)


# ------------------------------------------------------------------------------------------------
# RGB and depth frames: flagged rows, the take still ingested
# ------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def flawed(base, tmp_path_factory):
    """One take with a different defect in each of frames 1-5, ingested once."""
    tmp = tmp_path_factory.mktemp("flawed")
    take = take_copy(base, tmp, "flawed")
    (take / "rgb" / "000001.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage, not an image")   # corrupt
    (take / "rgb" / "000002.png").write_bytes(b"")                                          # empty
    (take / "rgb" / "000003.png").unlink()                                                  # missing
    np.save(take / "depth" / "000004.npy", np.ones((240, 320), np.float32))                # wrong size
    np.save(take / "depth" / "000005.npy", np.full((480, 640), np.nan, np.float32))         # NaN
    wh = tmp / "warehouse"
    shutil.copytree(base["warehouse"], wh)
    r = runner.invoke(app, ["--warehouse", str(wh), "ingest", str(take)])
    return {"take": take, "warehouse": wh, "result": r}


@pytest.mark.parametrize("frame, status, file", [
    (1, "unreadable_rgb", "rgb/000001.png"),
    (2, "unreadable_rgb", "rgb/000002.png"),
    (3, "missing_rgb", None),
    (4, "depth_size_mismatch", "depth/000004.npy"),
    (5, "all_zero_depth", "depth/000005.npy"),
])
def test_bad_frames_are_flagged_rows(flawed, frame, status, file):
    r = flawed["result"]
    assert r.exit_code == 0, r.output
    rows = frames_of(flawed["warehouse"], "flawed")
    assert len(rows) == N_FRAMES
    assert rows[frame]["status"] == status, rows[frame]
    assert rows[frame]["message"]
    if file:
        assert Path(file).name in rows[frame]["message"]
    assert rows[0]["status"] == "ok" and rows[N_FRAMES - 1]["status"] == "ok"


def test_truncated_video_flags_the_lost_frames(base, wh, tmp_path):
    take = take_copy(base, tmp_path, "truncated_video", video=True)
    data = (take / "rgb.mp4").read_bytes()
    (take / "rgb.mp4").write_bytes(data[: int(len(data) * 0.6)])
    r = cli("ingest", str(take))
    assert r.exit_code == 0, r.output
    rows = frames_of(wh, "truncated_video")
    lost = [f for f, row in rows.items() if row["status"] != "ok"]
    assert len(rows) == N_FRAMES and lost and lost == list(range(lost[0], N_FRAMES))  # the tail is lost
    # (an 8-frame mp4v file cut at 60 % loses its index, so here every frame is; see test_take_reader
    # for a longer video whose frames before the cut are salvaged)
    assert all(rows[f]["status"] == "unreadable_rgb" and "truncated" in rows[f]["message"]
               and "rgb.mp4" in rows[f]["message"] for f in lost)


def _depth_take(base, tmp_path, name, transform) -> Path:
    take = take_copy(base, tmp_path, name)
    for f in sorted((take / "depth").glob("*.npy")):
        np.save(f, transform(np.load(f)))
    return take


@pytest.mark.parametrize("name, transform", [
    ("zero_depth", lambda d: np.zeros_like(d)),
    ("nan_depth", lambda d: np.full_like(d, np.nan)),
    ("mm_depth", lambda d: (d * 1000.0).astype(np.float32)),  # millimetres written as float metres
])
def test_untrustworthy_depth_stops_the_take(base, wh, tmp_path, name, transform):
    """Issue 19: depth that cannot be trusted stops the take with a one-line error saying what is
    wrong with the depth and how to fix it. The stages before the depth check (frames, the detector's
    hand keypoints) keep what they computed; nothing depth-derived is written for the take."""
    take = _depth_take(base, tmp_path, name, transform)
    line = assert_one_line_error(cli("ingest", str(take)), "depth", "--accept-bad-depth")
    assert name in line or str(take) in line
    assert_readable(wh)
    for table in ("aligned_keypoints", "gripper_poses", "object_keypoints"):
        n = query(f"SELECT count(*) AS n FROM {table} WHERE take = '{name}'", wh).column("n")[0].as_py()
        assert n == 0, (table, n)


def test_depth_missing_at_the_hands_in_a_third_of_the_frames_is_recorded_and_warned_once(base, wh, tmp_path):
    """Issue 38: depth NaN in 3 of the 8 frames passed every check without a word (exit 0). The share of
    frames and of each hand's detections without depth at the hand is recorded (hand_presence,
    ingest_metrics) and, over docs/ingest.md's 15 %, warned about in one line."""
    take = take_copy(base, tmp_path, "third_no_depth")
    for f in sorted((take / "depth").glob("*.npy"))[2:5]:   # a run of 3 frames: interpolated, not measured
        np.save(f, np.full_like(np.load(f), np.nan))
    r = cli("ingest", str(take))
    assert r.exit_code == 0, r.output
    said = [line for line in stderr_lines(r.stderr) if "depth is missing at the hands" in line]
    assert len(said) == 1 and said[0].startswith(
        "warning: hand_presence: take third_no_depth: depth is missing at the hands in 38 % of the frames "
        "with a hand (left 38 %, right 38 % of each hand's detections), over the 15 %"), r.stderr
    for table in ("hand_presence", "ingest_metrics"):
        got = query(f"SELECT take, depth_missing_fraction AS hand, depth_missing_frame_fraction AS frames FROM {table} "
                    "ORDER BY take, hand", wh).to_pylist()
        assert [(g["take"], g["hand"], g["frames"]) for g in got] == [
            ("synth_pouring_s0000", 0.0, 0.0), ("synth_pouring_s0000", 0.0, 0.0),
            ("third_no_depth", 3 / 8, 3 / 8), ("third_no_depth", 3 / 8, 3 / 8)], (table, got)
    r = cli("ingest", str(base["take"]))                   # the intact take: nothing to say
    assert r.exit_code == 0 and "depth is missing" not in r.stderr


# ------------------------------------------------------------------------------------------------
# hands
# ------------------------------------------------------------------------------------------------

def test_take_with_one_hand_has_no_trajectory_for_the_other(base, wh, tmp_path):
    take = take_copy(base, tmp_path, "one_hand")
    r = cli("ingest", str(take), "-d", "precomputed", "--predictions", str(base["preds"]["right_only"]))
    assert r.exit_code == 0, r.output
    rows = query("SELECT hand, count(*) AS n, count(*) FILTER (WHERE valid) AS valid FROM gripper_poses "
                 "WHERE take = 'one_hand' GROUP BY hand", wh).to_pylist()
    by = {row["hand"]: row for row in rows}
    assert by["left"]["n"] == N_FRAMES and by["left"]["valid"] == 0      # flagged, not invented
    assert by["right"]["valid"] == N_FRAMES


def test_take_with_no_hands_is_refused_with_one_line(base, wh, tmp_path):
    """A hand never seen: `augment` refuses to build a database from it with a one-line message
    (issue 19: ingest may record the take, or stop it, with such a message)."""
    from demoforge.flows.augment import augment_take_flow
    from demoforge.lib.errors import is_user_error

    take = take_copy(base, tmp_path, "no_hands")
    r = cli("ingest", str(take), "-d", "precomputed", "--predictions", str(base["preds"]["none"]))
    if r.exit_code == 2:
        assert_one_line_error(r, "hand")
    else:
        assert r.exit_code == 0, r.output
        # `demoforge augment` cannot pass --predictions; the flow takes the detector's options
        with pytest.raises(Exception, match="hand") as refused:
            augment_take_flow(str(take), str(wh), augment=AugmentOptions(n=20, n_mirrored=10), show_progress=False,
                              ingest=IngestOptions(detector="precomputed",
                                                   detector_options={"path": str(base["preds"]["none"])}))
        assert is_user_error(refused.value)
    assert query("SELECT count(*) AS n FROM episodes WHERE take = 'no_hands'", wh).column("n")[0].as_py() == 0


# ------------------------------------------------------------------------------------------------
# scene files, warehouse files, concurrency
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("scene", [
    {"object_keypoints": [[0.0, 0.1, 0.2]] * 10},
    {"object_keypoints": [[0.0, 0.1]] * 11},
    {"object_keypoints": [[0.0, float("nan"), 0.2]] * 11},
    {"keypoints": []},
])
def test_scene_file_with_wrong_keypoints(wh, tmp_path, scene):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene))
    rejected(wh, "retrieve", "--task", "pouring", "--scene", str(path), needles=(str(path), "11 x 3"))


@pytest.mark.parametrize("command", [("simulate",), ("screen",), ("train-policy", "--closed-loop"), ("data-scaling",)])
def test_a_task_name_typo_is_one_line_listing_the_tasks(wh, command):
    rejected(wh, *command, "--task", "nosuch_task", needles=("unknown task 'nosuch_task'", "pouring, trash_in_bin"))


def test_scene_file_that_is_not_json(wh, tmp_path):
    path = tmp_path / "scene.json"
    path.write_text("object_keypoints: [1, 2, 3]")
    rejected(wh, "retrieve", "--task", "pouring", "--scene", str(path), needles=(str(path), "JSON"))


def test_truncated_warehouse_file_is_named_and_repaired_by_a_rerun(base, wh):
    f = next((wh / "frames").glob("**/data.parquet"))
    data = f.read_bytes()
    f.write_bytes(data[: len(data) // 2])
    line = assert_one_line_error(cli("sql", "SELECT count(*) AS n FROM frames"), str(f), "damaged",
                                 "run the command that wrote table 'frames' again")
    assert "frames" in line
    r = cli("ingest", str(base["take"]))  # the cached stage sees its file changed and recomputes it
    assert r.exit_code == 0, r.output
    assert_readable(wh)
    assert pq.read_table(f).num_rows == N_FRAMES


@pytest.mark.parametrize("damage", ["truncated", "not_parquet"])
def test_damaged_warehouse_file_is_one_line_on_every_read_path(base, wh, tmp_path, damage, prefect_api_env):
    """`tables`, `sql` on a catalog built before the damage, a flow reading the table, an export and
    `catalog`: each names the file and the fix in one line (exit 2), never a pyarrow traceback; in a
    process of its own, nothing follows that line (DuckDB objects kept alive by the error's traceback
    made nanobind print 40 lines of "leaked instance" at exit)."""
    query("SELECT count(*) FROM episodes", wh)  # the catalog is current: its views meet the damage
    f = next((wh / "episodes").glob("**/data.parquet"))
    data = f.read_bytes()
    f.write_bytes(data[: len(data) // 2] if damage == "truncated" else b"episode_id,task\n0,pouring\n")
    for args in (["tables"], ["sql", "SELECT count(*) AS n FROM episodes"], ["train-policy", "--task", "pouring"],
                 ["export", "lerobot", "--task", "pouring", "--out", str(tmp_path / "export")], ["catalog"]):
        assert_one_line_error(cli(*args), str(f), "damaged warehouse file",
                              "run the command that wrote table 'episodes' again"), args
    if damage == "truncated":
        p = subprocess.run([sys.executable, "-m", "demoforge.cli", "simulate", "--task", "pouring", "--episodes", "2"],
                           cwd=PROJECT, env={**os.environ, **prefect_api_env}, capture_output=True, text=True,
                           timeout=300)
        assert p.returncode == 2 and p.stderr.splitlines() == [p.stderr.strip()], p.stderr[-3000:]
        assert p.stderr.startswith(f"error: {f}: damaged warehouse file"), p.stderr


def test_two_ingests_of_the_same_take_at_once(base, wh, tmp_path):
    """Two processes ingest the same take into the same warehouse concurrently: both finish, and the
    warehouse holds the take once (atomic writes, one file per table and take)."""
    from prefect.settings import get_current_settings

    take = take_copy(base, tmp_path, "twice")
    env = {**os.environ, "PREFECT_API_URL": get_current_settings().api.url, "DEMOFORGE_WAREHOUSE": str(wh)}
    procs = [subprocess.Popen([sys.executable, "-m", "demoforge.cli", "ingest", str(take)], cwd=PROJECT, env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    for p, (out, err) in zip(procs, outs):
        assert p.returncode == 0, err[-2000:]
    assert len(frames_of(wh, "twice")) == N_FRAMES
    n = query("SELECT count(*) AS n FROM gripper_poses WHERE take = 'twice'", wh).column("n")[0].as_py()
    assert n == 2 * N_FRAMES
    assert not [p for p in wh.rglob("*") if p.is_file() and ".tmp" in p.name]  # no temporary leftovers
    assert_readable(wh)


# ------------------------------------------------------------------------------------------------
# LLM answers and LLM servers
# ------------------------------------------------------------------------------------------------

def _good_answer(n=20) -> str:
    wp = "[[0.1, 0.2, 0.3, 0, 0, 0, 1, 1], [0.1, -0.2, 0.3, 0, 0, 0, 1, 1]]"
    return "[" + ", ".join([wp] * n) + "]"


BAD_ANSWERS = [
    ("empty", ""),
    ("no_array", "I would move the left gripper to the cup, then tilt the right one to pour."),
    ("wrong_shape", "[[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]]"),
    ("non_finite", _good_answer().replace("0.2", "NaN")),
    ("truncated", _good_answer()[: len(_good_answer()) // 2]),  # salvaged: its complete waypoints are judged
]


def _llm_eval(wh: Path, options: dict, trials: int) -> list[dict]:
    from demoforge.flows.llm_eval import llm_eval

    llm_eval(str(wh), task="pouring", strategies=["single"], backend="openai",
             backend_options={"model": "stub-model", **options}, trials=trials, seed=0)
    return query("SELECT * FROM llm_trials WHERE strategy = 'single' ORDER BY trial", wh).to_pylist()


def test_bad_llm_answers_are_failed_trials(wh, monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", "sk-not-used")
    server = FakeOpenAIServer()
    server.script = [("ok", text, None) for _, text in BAD_ANSWERS]
    try:
        rows = _llm_eval(wh, {"base_url": server.url, "max_retries": 0}, trials=len(BAD_ANSWERS))
    finally:
        server.close()
    assert len(server.requests) == len(BAD_ANSWERS)
    assert [r["parse_status"] for r in rows] == [status for status, _ in BAD_ANSWERS]
    for r, (status, text) in zip(rows, BAD_ANSWERS):
        assert r["raw_answer"] == text and r["parse_detail"]
        if status == "truncated":  # the complete waypoints before the cut were executed in MuJoCo
            assert "kept 10 complete waypoint(s)" in r["parse_detail"] and r["sim_detail"]
        else:
            assert r["success"] is False and r["failure_reason"] == status and r["sim_detail"] == ""
    assert query("SELECT trials FROM report_table3 WHERE strategy = 'single'", wh).column(0)[0].as_py() == 5


@pytest.mark.parametrize("server_kind, detail", [
    ("dead", "LLMRequestError"),
    ("slow", "LLMTimeoutError"),
    ("5xx", "500"),
])
def test_llm_server_dead_slow_or_failing_is_a_failed_trial(wh, monkeypatch, server_kind, detail):
    monkeypatch.setenv("OPENAI_API_KEY", "sk-not-used")
    server = FakeOpenAIServer()
    server.script = {"slow": [("sleep", 3.0)], "5xx": [("status", 500, '{"error": "overloaded"}')],
                     "dead": [("ok", _good_answer(), None)]}[server_kind]
    url = server.url
    if server_kind == "dead":
        server.close()  # nothing listens on that port any more
    try:
        rows = _llm_eval(wh, {"base_url": url, "max_retries": 1, "backoff_s": 0.01, "timeout_s": 0.5}, trials=1)
    finally:
        if server_kind != "dead":
            server.close()
    (r,) = rows
    assert r["parse_status"] == "llm_error" and r["failure_reason"] == "llm_error" and r["success"] is False
    assert detail in r["parse_detail"], r["parse_detail"]
    assert_readable(wh)


# ------------------------------------------------------------------------------------------------
# keys and secrets
# ------------------------------------------------------------------------------------------------

FAKE_KEY = "sk-demoforge-FAKE-KEY-7f3a9c2e41d8b6"


def test_api_key_is_in_no_file_the_run_wrote(base, tmp_path):
    """`demoforge llm-eval` with the openai backend and a recognisable key, in a process of its own
    (its own Prefect home, temporary API server and TMPDIR under tmp_path): the stub server receives
    the key, and no file the run wrote -- tables, LLM cache, Prefect's database, results and logs,
    temporary files -- nor its output contains it."""
    server = FakeOpenAIServer()
    server.script = [("ok", "I am not sure.", None)]
    wh, home, cwd, tmp = tmp_path / "warehouse", tmp_path / "prefect_home", tmp_path / "cwd", tmp_path / "tmp"
    shutil.copytree(base["warehouse"], wh)
    for d in (home, cwd, tmp):
        d.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_API")}
    env.update(PREFECT_HOME=str(home), DEMOFORGE_WAREHOUSE=str(wh), TMPDIR=str(tmp), OPENAI_API_KEY=FAKE_KEY,
               OPENAI_BASE_URL=server.url, DEMOFORGE_LLM_MODEL="stub-model",
               PYTHONPATH=os.pathsep.join([str(PROJECT), env.get("PYTHONPATH", "")]))
    try:
        p = subprocess.run([sys.executable, "-m", "demoforge.cli", "llm-eval", "--task", "pouring", "--backend", "openai",
                            "-s", "single", "--trials", "2"], cwd=cwd, env=env, capture_output=True, text=True,
                           timeout=480)
    finally:
        server.close()
    assert p.returncode == 0, p.stderr[-3000:]
    assert server.requests and all(FAKE_KEY in r["headers"].get("Authorization", "") for r in server.requests)
    assert FAKE_KEY not in p.stdout + p.stderr
    files = [f for d in (wh, home, cwd, tmp) for f in d.rglob("*") if f.is_file()]
    assert any(f.suffix == ".db" for f in home.rglob("*"))  # Prefect's database was written here
    assert any("_llm_cache" in str(f) for f in files)
    leaked = [str(f) for f in files if FAKE_KEY.encode() in f.read_bytes()]
    assert leaked == []
    rows = query("SELECT parse_status FROM llm_trials", wh).column(0).to_pylist()
    assert rows == ["no_array", "no_array"]
