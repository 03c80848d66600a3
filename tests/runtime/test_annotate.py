"""Annotating a recorded take: the annotation server (demoforge.runtime.annotate) and its page in a real headless
Chromium, whether a take is annotated, ingest and augment of takes without annotations, custom tasks, and
one-line user errors of the CLI. (What the page writes: tests/lib/annotate/test_model.py; custom tasks:
tests/lib/takes/test_task_definition.py.)"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from demoforge.lib.annotate import (
    annotation_status, build_annotations, library_task, not_annotated_message, suggest_closed_ranges, write_annotations,
)
from demoforge.lib.takes import TakeError, open_take
from demoforge.lib.trajectories.augmentation.options import AugmentOptions
from demoforge.lib.ingest.options import IngestOptions
from tests.support.paths import REPO_ROOT

ROOT = REPO_ROOT
N_FRAMES = 40


@pytest.fixture(scope="module")
def pouring_take(tmp_path_factory):
    """A 40-frame synthetic pouring take (with the generator's exact annotations.json)."""
    from demoforge.lib.synth.take import generate_take

    out = tmp_path_factory.mktemp("annotate") / "synth_pouring_s0000"
    generate_take("pouring", 0, False, out, video=False, max_frames=N_FRAMES)
    return out


@pytest.fixture()
def raw_take(pouring_take, tmp_path):
    """The take as a new user has it: frames, depth and camera.json, no annotations.json."""
    out = tmp_path / "my_take"
    shutil.copytree(pouring_take, out)
    (out / "annotations.json").unlink()
    return out


def _cli(*args: str, warehouse: Path, timeout: int = 600, api: dict | None = None) -> subprocess.CompletedProcess:
    """`demoforge ARGS` in a process of its own; ``api``: the session's Prefect API (prefect_api_env) for a
    command that runs a flow, instead of a temporary server of its own."""
    env = {**os.environ, **(api or {}), "PYTHONPATH": str(ROOT), "DEMOFORGE_WAREHOUSE": str(warehouse),
           "MUJOCO_GL": "egl"}
    return subprocess.run([sys.executable, "-m", "demoforge.cli", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout)


def _one_line_error(r: subprocess.CompletedProcess, *needles: str) -> str:
    assert r.returncode == 2, r.stdout + r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert "Traceback" not in r.stderr + r.stdout
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


# ------------------------------------------------------------------------------------------------ lib

def test_annotation_status_needs_every_keypoint_of_the_task(raw_take):
    take = open_take(raw_take)
    assert annotation_status(take).annotated is False
    t = library_task("pouring")
    write_annotations(raw_take / "annotations.json",
                      build_annotations(t, {"bottle_base": [100, 100]}, 0, {}, N_FRAMES))
    st = annotation_status(open_take(raw_take))
    assert not st.annotated and "1 of 11" in st.detail and "cup_rim_right" in st.detail
    assert not_annotated_message("TAKE", st.detail).startswith("TAKE: not annotated yet (1 of 11")


# ------------------------------------------------------------------------------------------------ CLI

def test_cli_user_errors_are_one_line_without_traceback(raw_take, tmp_path, prefect_api_env):
    """The first in a process of its own (a fresh interpreter's stderr is that one line, nothing else);
    the others, which all fail before any flow starts, in this process (typer's CliRunner)."""
    from typer.testing import CliRunner

    from demoforge.cli import app

    wh = tmp_path / "wh"

    def cli(*args):
        r = CliRunner().invoke(app, list(args), env={"DEMOFORGE_WAREHOUSE": str(wh)})
        return subprocess.CompletedProcess(list(args), r.exit_code, r.stdout, r.stderr)

    # the session's Prefect API: a command that failed inside a flow would start no server of its own
    _one_line_error(_cli("ingest", str(tmp_path / "nowhere"), warehouse=wh, api=prefect_api_env), "no such take folder")
    _one_line_error(cli("augment", str(tmp_path / "nowhere")), "no such take folder")
    _one_line_error(cli("annotate", str(tmp_path / "nowhere")), "no such take folder")
    _one_line_error(cli("ingest-folder", str(tmp_path / "nowhere")), "no such folder")
    cam = json.loads((raw_take / "camera.json").read_text())
    (raw_take / "camera.json").write_text("{broken")
    _one_line_error(cli("ingest", str(raw_take)), "camera.json", "not valid JSON")
    (raw_take / "camera.json").unlink()
    _one_line_error(cli("augment", str(raw_take)), "camera.json is missing")
    (raw_take / "camera.json").write_text(json.dumps(cam))
    (raw_take / "annotations.json").write_text(json.dumps({"object_keypoints_2d": {"frame": 0, "names": ["a"]}}))
    _one_line_error(cli("ingest", str(raw_take)), "annotations.json", "lacks key 'uv'")
    _one_line_error(cli("annotate", str(raw_take), "--task", "pouring"), "annotations.json")
    (raw_take / "annotations.json").unlink()
    _one_line_error(cli("annotate", str(raw_take), "--task", "juggling"), "unknown task 'juggling'")
    _one_line_error(cli("annotate", str(raw_take), "--task", "custom"), "--keypoints")
    assert not (wh / "frames").exists()  # nothing ran


def test_ingest_without_annotations_completes_and_augment_refuses(raw_take, tmp_path, prefect_api_env):
    from demoforge.schemas.catalog import query

    wh = tmp_path / "wh"
    r = _cli("ingest", str(raw_take), warehouse=wh, api=prefect_api_env)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "Traceback" not in r.stderr
    warn = f"warning: object_keypoints: {raw_take}: not annotated yet (no annotations.json): run demoforge annotate {raw_take}"
    assert warn in r.stderr.splitlines()
    # one line per warning: not also Prefect's "WARNING | Task run 'object_keypoints-...'" line
    assert r.stderr.count("not annotated yet") == 1 and "| WARNING |" not in r.stderr, r.stderr
    assert "gripper_poses" in r.stdout and "object_keypoints" not in r.stdout
    n = query("SELECT count(*) AS n, count(*) FILTER (WHERE valid) AS ok FROM gripper_poses", wh).to_pylist()[0]
    assert n["n"] == 2 * N_FRAMES and n["ok"] > N_FRAMES
    assert not (wh / "object_keypoints").exists()
    r = _cli("augment", str(raw_take), "-n", "20", "--mirrored", "10", warehouse=wh, api=prefect_api_env)
    _one_line_error(r, f"{raw_take}: not annotated yet (no annotations.json): run demoforge annotate {raw_take}")
    assert not (wh / "episodes").exists()


def test_annotating_after_an_ingest_keeps_its_hand_stages(prefect_api, raw_take, pouring_take, tmp_path):
    """ingest -> annotate -> ingest: detection and alignment come from the cache, the rest is redone."""
    from demoforge.flows.ingest import ingest_take
    from demoforge.schemas.catalog import query

    wh = tmp_path / "wh"
    first = ingest_take(str(raw_take), str(wh), task="pouring", show_progress=False)
    assert first["object_keypoints"] is None
    hk = Path(first["hand_keypoints"].path)
    stamp = hk.stat().st_mtime_ns
    okp = json.loads((pouring_take / "annotations.json").read_text())["object_keypoints_2d"]
    write_annotations(raw_take / "annotations.json",
                      build_annotations(library_task("pouring"), dict(zip(okp["names"], okp["uv"])), 0,
                                        {"left": [[5, 20]]}, N_FRAMES))
    second = ingest_take(str(raw_take), str(wh), show_progress=False)  # the task now from annotations.json
    for stage in ("frames", "hand_keypoints", "aligned_keypoints"):
        assert (second[stage].path, second[stage].content_hash) == (first[stage].path, first[stage].content_hash)
    assert hk.stat().st_mtime_ns == stamp  # not rewritten: the detector did not run again
    assert second["object_keypoints"].rows == 11
    g = query("SELECT hand, state_method FROM gripper_poses WHERE frame = 0 ORDER BY hand", wh).to_pylist()
    assert [r["state_method"] for r in g] == ["manual", "manual"]


def test_ingest_folder_lists_unannotated_takes_as_needing_annotation(prefect_api, pouring_take, tmp_path):
    from demoforge.flows.ingest_folder import ingest_folder
    from demoforge.schemas.catalog import query

    inbox = tmp_path / "inbox"
    shutil.copytree(pouring_take, inbox / "annotated")
    shutil.copytree(pouring_take, inbox / "raw")
    (inbox / "raw" / "annotations.json").unlink()
    (inbox / "raw" / "take.json").unlink()  # take ids from the folder names
    (inbox / "annotated" / "take.json").unlink()
    shutil.copytree(pouring_take, inbox / "broken")
    (inbox / "broken" / "take.json").unlink()
    (inbox / "broken" / "camera.json").write_text("[]")
    wh = tmp_path / "wh"
    rows = ingest_folder(str(inbox), str(wh), task="pouring", augment=AugmentOptions.half_mirrored(20))
    by = {r["take"]: r for r in rows}
    assert by["annotated"]["status"] == "ingested" and by["annotated"]["episodes"] > 0
    assert by["raw"]["status"] == "needs_annotation" and by["raw"]["gripper_rows"] == 2 * N_FRAMES
    assert "not annotated yet" in by["raw"]["error"] and by["raw"]["episodes"] == 0
    assert by["broken"]["status"] == "failed" and "camera.json" in by["broken"]["error"]
    eps = query("SELECT take, count(*) AS n FROM episodes GROUP BY take", wh).to_pylist()
    assert eps == [{"take": "annotated", "n": 21}]  # the demonstration and 20 generated
    got = query("SELECT take, status FROM folder_ingests ORDER BY take", wh).to_pylist()
    assert got == [{"take": "annotated", "status": "ingested"}, {"take": "broken", "status": "failed"},
                   {"take": "raw", "status": "needs_annotation"}]


def test_custom_task_is_annotated_ingested_and_augmented(prefect_api, pouring_take, raw_take, tmp_path):
    """A task the library does not know: keypoints named by the user, arms stated on the page."""
    from demoforge.runtime.annotate import AnnotationSession
    from demoforge.flows.augment import augment_take_flow
    from demoforge.schemas.catalog import query

    (raw_take / "take.json").unlink()  # a real recording has no take.json
    shutil.rmtree(raw_take / "ground_truth")
    wh = tmp_path / "wh"
    exact = json.loads((pouring_take / "annotations.json").read_text())["object_keypoints_2d"]
    uv = dict(zip(exact["names"], exact["uv"]))
    mine = ["jug:j_base", "jug:j_left", "jug:j_right", "jug:j_shoulder", "jug:j_mouth", "glass:g_base",
            "glass:g_center", "glass:g_front", "glass:g_back", "glass:g_left", "glass:g_right"]
    where = {m.split(":")[1]: uv[n] for m, n in zip(mine, exact["names"])}  # the points of the pouring objects
    session = AnnotationSession(raw_take, wh, task="custom:serve_drink", keypoints=",".join(mine))
    assert session.task.object_names == ("jug", "glass") and session.task.object_arms == (None, None)
    task = session.task.to_json()
    task["objects"][0]["arm"], task["objects"][1]["arm"] = "right", "left"   # chosen on the page
    points = {k: where[k] for k in list(where)[:5]}
    saved = session.save({"frame": 0, "points": points, "ranges": {"left": [[2, 30]]}, "task": task})
    assert not saved["status"]["annotated"]
    assert saved["status"]["detail"].startswith("5 of 11 object keypoints placed, missing g_base, g_center")
    bad = json.loads(json.dumps(task))
    bad["objects"][1]["keypoints"][0] = "j_base"
    with pytest.raises(TakeError, match="keypoint names must be unique"):
        session.save({"frame": 0, "points": {}, "ranges": {}, "task": bad})
    saved = session.save({"frame": 0, "points": where, "ranges": {"left": [[2, 30]]}, "task": task})
    assert saved["status"] == {"annotated": True, "detail": ""}
    ann = open_take(raw_take).annotations
    assert ann.task.name == "serve_drink" and ann.task.object_arm_index().tolist() == [1, 0]

    preds = tmp_path / "preds.npz"
    _write_gt_predictions(pouring_take, preds)
    augment_take_flow(str(raw_take), str(wh), augment=AugmentOptions(n=30, n_mirrored=10), show_progress=False,
                      ingest=IngestOptions(detector="precomputed", detector_options={"path": str(preds)}))
    kp = query("SELECT name, valid, source FROM object_keypoints ORDER BY keypoint", wh).to_pylist()
    assert [k["name"] for k in kp] == list(where)
    assert all(k["valid"] and k["source"] == "annotation+depth" for k in kp)
    eps = query("SELECT task, take, kind, count(*) AS n FROM episodes GROUP BY ALL ORDER BY kind", wh).to_pylist()
    assert {(e["task"], e["take"]) for e in eps} == {("serve_drink", "my_take")}
    assert {e["kind"]: e["n"] for e in eps} == {"original": 1, "translated": 20, "mirrored": 10}
    g = query("SELECT hand, state_method FROM gripper_poses WHERE frame = 10 ORDER BY hand", wh).to_pylist()
    assert [r["state_method"] for r in g] == ["manual", "manual"]  # the page's ranges are the labels


def _write_gt_predictions(take: Path, out: Path) -> None:
    """Detector predictions for a take without ground truth: the synthetic take's exact joints."""
    import pyarrow.parquet as pq

    from demoforge.schemas.reads.per_hand import arrays

    T, a = arrays(pq.read_table(take / "ground_truth" / "gt_hand_joints.parquet"), "joints_camera", "joints_px",
                  "present")
    rows = [(f, h) for f in range(T) for h in range(2) if a["present"][f, h]]
    np.savez(out, frame=np.array([f for f, _ in rows]), hand=np.array([("left", "right")[h] for _, h in rows]),
             joints_cam=np.stack([a["joints_camera"][f, h] for f, h in rows]),
             joints_px=np.stack([a["joints_px"][f, h] for f, h in rows]),
             confidence=np.ones(len(rows)))


def test_server_loads_an_existing_file_serves_frames_and_refuses_bad_saves(pouring_take, tmp_path):
    """The page's API: an existing annotations.json is what the page starts from; a bad save changes nothing."""
    import urllib.error
    import urllib.request

    import cv2

    from demoforge.runtime.annotate import AnnotationSession, server_url, start_server

    take = tmp_path / "take"
    shutil.copytree(pouring_take, take, ignore=shutil.ignore_patterns("ground_truth"))
    before = (take / "annotations.json").read_bytes()
    original = json.loads(before)
    session = AnnotationSession(take)  # task from take.json (pouring)
    server = start_server(session, port=0)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    url, token = _base_url(server), server.gate.token
    assert server_url(server) == f"{url}?token={token}"

    def post(path: str, body: dict):
        req = urllib.request.Request(url + path, data=json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": "application/json", "X-Demoforge-Token": token})
        return json.load(urllib.request.urlopen(req, timeout=30))

    try:
        st = json.load(urllib.request.urlopen(url + f"api/state?token={token}", timeout=30))
        assert st["exists"] and st["current"]["ranges_from"] == "annotations.json" and st["ingest"] is None
        okp = original["object_keypoints_2d"]
        assert st["current"]["points"] == {n: list(map(float, uv)) for n, uv in zip(okp["names"], okp["uv"])}
        assert st["current"]["ranges"] == original["gripper_closed_ranges"]
        jpg = urllib.request.urlopen(url + f"api/frame/7.jpg?token={token}", timeout=30).read()
        img = cv2.imdecode(np.frombuffer(jpg, np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (480, 640, 3)
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(url + f"api/frame/{N_FRAMES}.jpg?token={token}", timeout=30)
        assert e.value.code == 400 and "out of range" in json.load(e.value)["error"]
        with pytest.raises(urllib.error.HTTPError) as e:
            post("api/save", {"frame": 0, "points": st["current"]["points"], "task": st["task"],
                              "ranges": {"left": [[5, 3]]}})
        assert e.value.code == 400 and "need 0 <= start < end" in json.load(e.value)["error"]
        assert (take / "annotations.json").read_bytes() == before
        moved = dict(st["current"]["points"], cup_base=[300.0, 210.0])
        out = post("api/save", {"frame": 0, "points": moved, "task": st["task"], "ranges": {"left": [[5, 9]]}})
        assert out["status"] == {"annotated": True, "detail": ""}
    finally:
        server.shutdown()
        server.server_close()
    saved = json.loads((take / "annotations.json").read_text())
    assert saved["object_keypoints_2d"]["uv"][okp["names"].index("cup_base")] == [300.0, 210.0]
    assert saved["gripper_closed_ranges"] == {"left": [[5, 9]], "right": []}
    assert sorted(p.name for p in take.iterdir() if p.name.startswith(".")) == []  # no temp file left


def _base_url(server) -> str:
    host, port = server.server_address[:2]
    return f"http://{host}:{port}/"


def _request(server, method: str, path: str, headers: dict, body: bytes | None = None) -> tuple[int, str]:
    """One request with exactly these headers (Host included when given): (status, error text)."""
    import http.client

    conn = http.client.HTTPConnection(*server.server_address[:2], timeout=30)
    try:
        conn.putrequest(method, path, skip_host="Host" in headers, skip_accept_encoding=True)
        for name, value in headers.items():
            conn.putheader(name, value)
        if body is not None:
            conn.putheader("Content-Length", str(len(body)))
        conn.endheaders(body)
        answer = conn.getresponse()
        data = answer.read()
        return answer.status, (json.loads(data).get("error", "") if answer.status >= 400 else "")
    finally:
        conn.close()


def _take_files(take: Path) -> dict:
    return {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in take.iterdir() if p.is_file()}


def test_every_route_of_the_annotation_server_passes_the_request_gate(pouring_take, tmp_path):
    """A web page in another tab, DNS rebinding, a missing or wrong token, a body that is not JSON or is
    too large: refused (403 / 415 / 413) on every route the server has, and nothing is written."""
    from demoforge.runtime.annotate import PAGE_ROUTE, ROUTES, AnnotationSession, start_server
    from demoforge.lib.annotate.request_gate import MAX_BODY_BYTES

    take = tmp_path / "take"
    shutil.copytree(pouring_take, take, ignore=shutil.ignore_patterns("ground_truth"))
    server = start_server(AnnotationSession(take), port=0)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    port, token = server.server_address[1], server.gate.token
    # The token is random: change its first character to one it does not have.
    wrong_token = ("y" if token[0] == "x" else "x") + token[1:]
    own = {"Host": f"127.0.0.1:{port}", "Origin": f"http://127.0.0.1:{port}"}
    ann = json.loads((take / "annotations.json").read_text())
    okp = ann["object_keypoints_2d"]
    save = {"frame": 0, "points": dict(zip(okp["names"], okp["uv"])), "ranges": {"left": [[1, 2]]}}
    before = _take_files(take)
    assert PAGE_ROUTE in ROUTES and {(r.method, r.example) for r in ROUTES} >= {
        ("GET", "/"), ("GET", "/api/state"), ("GET", "/api/frame/0.jpg"), ("POST", "/api/points"), ("POST", "/api/save")}
    try:
        for route in ROUTES:
            body = json.dumps(save).encode() if route.method == "POST" else None
            json_ct = {"Content-Type": "application/json"} if body is not None else {}
            with_token = f"{route.example}?token={token}"
            refused = [
                ("no token", route.example, {**own, **json_ct}, 403, "session token"),
                ("wrong token", f"{route.example}?token={wrong_token}", {**own, **json_ct}, 403, "session token"),
                ("wrong token header", route.example, {**own, **json_ct, "X-Demoforge-Token": token[:-1]}, 403,
                 "session token"),
                ("DNS rebinding", with_token, {**own, **json_ct, "Host": f"evil.example:{port}"}, 403, "Host"),
                ("foreign port", with_token, {**own, **json_ct, "Host": f"127.0.0.1:{port + 1}"}, 403, "Host"),
            ]
            if body is not None:
                refused += [
                    ("cross-origin POST", with_token, {**own, **json_ct, "Origin": "http://evil.example"}, 403,
                     "may not change"),
                    ("text/plain body", with_token, {**own, "Content-Type": "text/plain"}, 415, "application/json"),
                    ("no content type", with_token, own, 415, "application/json"),
                ]
            for case, path, headers, status, needle in refused:
                got, error = _request(server, route.method, path, headers, body)
                assert (got, needle in error) == (status, True), (route.example, case, got, error)
            if body is not None:
                big = b'{"frame": 0, "pad": "' + b"x" * MAX_BODY_BYTES + b'"}'
                got, error = _request(server, route.method, with_token, {**own, **json_ct}, big)
                assert got == 413 and "over the limit" in error, (route.example, got, error)
            assert _take_files(take) == before, route.example          # nothing written, nothing touched
        # the gate comes before the routes: an unknown path is refused, not answered, without the token
        assert _request(server, "GET", "/nowhere", own)[0] == 403
        assert _request(server, "GET", f"/nowhere?token={token}", own)[0] == 404
        # the page's own requests pass (localhost is the same loopback page)
        assert _request(server, "GET", "/api/state", {"Host": f"localhost:{port}", "X-Demoforge-Token": token})[0] == 200
        got, _ = _request(server, "POST", "/api/save", {**own, "Content-Type": "application/json; charset=utf-8",
                                                        "X-Demoforge-Token": token}, json.dumps(save).encode())
        assert got == 200
    finally:
        server.shutdown()
        server.server_close()
    assert json.loads((take / "annotations.json").read_text())["gripper_closed_ranges"]["left"] == [[1, 2]]


def test_annotate_command_serves_its_take_and_task_until_ctrl_c(raw_take, tmp_path):
    """`demoforge annotate` on its main path: the printed URL (with the token) serves the take with the
    task of --task/--keypoints, a save writes annotations.json, Ctrl-C ends it cleanly."""
    import signal
    import urllib.request

    names = [f"jug:j{i}" for i in range(5)] + [f"glass:g{i}" for i in range(6)]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "DEMOFORGE_WAREHOUSE": str(tmp_path / "wh")}
    proc = subprocess.Popen([sys.executable, "-m", "demoforge.cli", "annotate", str(raw_take), "--task",
                             "custom:serve_drink", "--keypoints", ",".join(names), "--port", "0"], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = proc.stdout.readline().strip()
        if not url:  # it ended instead of serving: say why
            pytest.fail(f"annotate exited ({proc.wait(60)}): {proc.stderr.read()[-2000:]}")
        assert url.startswith("http://127.0.0.1:") and "/?token=" in url, url
        base, token = url.split("?token=")
        st = json.load(urllib.request.urlopen(f"{base}api/state?token={token}", timeout=30))
        assert st["path"] == str(raw_take) and st["n_frames"] == N_FRAMES and not st["exists"]
        assert st["task"]["name"] == "serve_drink" and [o["name"] for o in st["task"]["objects"]] == ["jug", "glass"]
        task = st["task"]
        task["objects"][0]["arm"], task["objects"][1]["arm"] = "right", "left"
        body = json.dumps({"frame": 3, "points": {"j0": [10.0, 20.0]}, "ranges": {"left": [[2, 9]]}, "task": task})
        req = urllib.request.Request(f"{base}api/save", data=body.encode(), method="POST",
                                     headers={"Content-Type": "application/json", "X-Demoforge-Token": token})
        saved = json.load(urllib.request.urlopen(req, timeout=30))
        assert saved["status"]["detail"].startswith("1 of 11 object keypoints placed")
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0 and "Traceback" not in err, err
    written = json.loads((raw_take / "annotations.json").read_text())
    assert written["task"]["name"] == "serve_drink" and written["object_keypoints_2d"]["frame"] == 3
    assert written["gripper_closed_ranges"] == {"left": [[2, 9]], "right": []}


# ------------------------------------------------------------------------------------------------ browser

def test_annotation_page_in_a_real_browser(prefect_api, raw_take, tmp_path):
    """Open the page in headless Chromium, click the 11 keypoints, edit a pre-filled range, save."""
    from demoforge.runtime.annotate import AnnotationSession, server_url, start_server
    from demoforge.flows.ingest import ingest_take
    from demoforge.schemas.reads.per_hand import arrays
    from tests.support.cdp import Browser, chromium_path

    assert chromium_path() is not None, "chromium is not installed: run scripts/setup.sh (apt-get install chromium)"
    wh = tmp_path / "wh"
    ingest_take(str(raw_take), str(wh), show_progress=False)   # gives the timeline its fingertip distances
    import pyarrow.parquet as pq

    _, gp = arrays(pq.read_table(next((wh / "gripper_poses").rglob("*.parquet"))), "fingertip_distance")
    suggested = suggest_closed_ranges(gp["fingertip_distance"])
    assert suggested["left"], "the take's left hand closes: the suggestion must have a range to edit"

    session = AnnotationSession(raw_take, wh)        # the task comes from the take (synthetic take.json)
    server = start_server(session, port=0)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    browser = Browser.start(tmp_path / "chromium-profile")
    try:
        browser.goto(server_url(server))
        browser.wait_for("!!document.body && document.body.dataset.ready === '1'")
        assert browser.eval("JSON.stringify(annotator.ranges)") == json.dumps(suggested, separators=(",", ":"))
        names = browser.eval("annotator.task.keypoints.map(k => k.name)")
        assert names == list(library_task("pouring").keypoint_names)
        # click each keypoint where its object really is (the generator's exact projections)
        exact = _exact_uv(raw_take)
        canvas = browser.rect("#frame-canvas")
        sx, sy = canvas["width"] / 640, canvas["height"] / 480
        clicked = {}
        for i, name in enumerate(names):
            u, v = exact[name]
            x, y = canvas["left"] + (u + 0.5) * sx, canvas["top"] + (v + 0.5) * sy
            browser.click(x, y)
            browser.wait_for(f"annotator.info[{json.dumps(name)}] !== undefined")
            clicked[name] = browser.eval(f"annotator.points[{json.dumps(name)}]")
            # mouse events land on whole CSS pixels: within one CSS pixel (in image pixels) of the target
            assert abs(clicked[name][0] - u) <= 1 / sx + 0.05 and abs(clicked[name][1] - v) <= 1 / sy + 0.05
        assert browser.eval("document.getElementById('kp-count').textContent").startswith("11 of 11")
        world = browser.eval("annotator.info['cup_base'].world")
        assert world is not None and len(world) == 3
        # edit the first left range: type a new start frame, leave the field with Tab
        start0, end0 = suggested["left"][0]
        new_start = start0 + 2 if end0 - start0 > 3 else start0
        browser.click_element('.range-start[data-hand="left"][data-i="0"]')
        browser.eval("document.activeElement.select()")
        browser.type_text(str(new_start))
        browser.press("Tab", 9)
        browser.wait_for(f"annotator.ranges.left[0][0] === {new_start}")
        browser.screenshot(tmp_path / "annotate.png")
        browser.click_element("#save")
        browser.wait_for("document.getElementById('message').className === 'ok'")
        msg = browser.eval("document.getElementById('message').textContent")
        assert "11 of 11 keypoints" in msg and "ready to ingest" in msg
    finally:
        browser.close()
        server.shutdown()
        server.server_close()
    saved = json.loads((raw_take / "annotations.json").read_text())
    assert saved["object_keypoints_2d"]["frame"] == 0 and saved["object_keypoints_2d"]["names"] == names
    assert np.allclose(saved["object_keypoints_2d"]["uv"], [clicked[n] for n in names])
    want = {s: [list(r) for r in suggested[s]] for s in ("left", "right")}
    want["left"][0][0] = new_start
    assert saved["gripper_closed_ranges"] == want
    assert saved["task"]["name"] == "pouring" and saved["task"]["library"] is True
    assert (tmp_path / "annotate.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    take = open_take(raw_take)
    assert annotation_status(take).annotated
    assert take.annotations.closed_mask(N_FRAMES)[new_start, 0]


def _exact_uv(take: Path) -> dict:
    """{name: [u, v]} of the generator's exact keypoint projections, kept inside the image."""
    import pyarrow.parquet as pq

    from demoforge.lib.ingest.alignment import project
    from demoforge.lib.geometry import transform_inverse, transform_points

    gt = pq.read_table(take / "ground_truth" / "gt_object_keypoints.parquet").to_pylist()
    first = next(r for r in gt if r["frame"] == 0)
    cam = open_take(take).camera
    pc = transform_points(transform_inverse(cam.T_world_camera), np.asarray(first["keypoints_world"], float))
    uv = np.clip(project(pc, cam.K), 1, [cam.width - 2, cam.height - 2])
    names = library_task("pouring").keypoint_names
    return {n: [round(float(a), 1), round(float(b), 1)] for n, (a, b) in zip(names, uv)}
