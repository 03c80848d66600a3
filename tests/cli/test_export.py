"""`demoforge export` (demoforge/cli/export.py): bad exports are refused before any Prefect run, in one line with
exit code 2."""

from __future__ import annotations

from tests.support.episodes import TASK


def test_cli_refuses_bad_exports_with_one_line_and_exit_2(episode_wh, tmp_path, monkeypatch):
    """User errors are caught before any Prefect run: exit code 2 and a message that says what to fix."""
    from typer.testing import CliRunner

    from demoforge.cli import app

    wh, _ = episode_wh
    monkeypatch.setenv("DEMOFORGE_WAREHOUSE", str(wh))
    runner = CliRunner()
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    (tmp_path / "old.rrd").write_bytes(b"x")
    (tmp_path / "other.hdf5").write_bytes(b"not ours")
    for args, msg in ((["export", "lerobot", "--task", TASK, "--out", str(foreign)], "not a demoforge export"),
                      (["export", "robomimic", "--task", TASK, "--out", str(tmp_path / "a.zip")], ".hdf5"),
                      (["export", "robomimic", "--task", TASK, "--out", str(tmp_path / "other.hdf5")],
                       "not a demoforge export"),
                      (["export", "lerobot", "--task", "juggling", "--out", str(tmp_path / "j")], "unknown task"),
                      (["export", "lerobot", "--task", "mix_bowl", "--out", str(tmp_path / "m")], "demoforge augment"),
                      (["export", "robomimic", "--task", TASK, "--out", str(tmp_path / "r.hdf5"),
                        "--valid-fraction", "1.5"], "--valid-fraction"),
                      (["view", "pouring/123456", "--rrd", str(tmp_path / "v.rrd")], "no episode 123456"),
                      (["view", "no_such_take", "--rrd", str(tmp_path / "v.rrd")], "neither a take folder"),
                      (["view", "pouring/0", "--rrd", str(tmp_path / "old.rrd")], "--overwrite"),
                      (["view", str(tmp_path), "--rrd", str(tmp_path / "v.rrd")], "demoforge ingest"),
                      (["view", "pouring/0", "--rrd", str(tmp_path / "v.txt")], ".rrd"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "i"), "--with-images"],
                       "demoforge ingest"),
                      (["export", "robomimic", "--task", TASK, "--out", str(tmp_path / "r.hdf5"), "--with-images"],
                       "lerobot` only"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "i"), "--with-images",
                        "--image-size", "33x20"], "--image-size"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "i"), "--image-size", "64x48"],
                       "needs --with-images"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "a"), "--robot", "aloha"],
                       "demoforge simulate --task pouring --robot aloha --gripper aloha"),
                      (["export", "robomimic", "--task", TASK, "--out", str(tmp_path / "a.hdf5"), "--robot", "aloha"],
                       "is for `export lerobot`"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "a"), "--unchecked"],
                       "--unchecked is for"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "a"), "--robot", "ur5"],
                       "--robot must be one of grippers, aloha"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "a"), "--robot", "aloha",
                        "--gripper", "robotiq"], "carries aloha or 2f140")):
        r = runner.invoke(app, args)
        assert r.exit_code == 2 and msg in r.stderr and len(r.stderr.strip().splitlines()) == 1, (args, r.output)
    assert (foreign / "notes.txt").read_text() == "keep me" and not (tmp_path / "j").exists()
    assert (tmp_path / "other.hdf5").read_bytes() == b"not ours"
    r = runner.invoke(app, ["export", "--help"])
    assert r.exit_code == 0 and "lerobot" in r.output and "robomimic" in r.output
