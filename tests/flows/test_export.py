"""The export and view commands through their Prefect flows: cached on the episode tables' content."""

from __future__ import annotations


import pytest

from tests.support.episodes import TASK, build_episode_warehouse


@pytest.fixture()
def small_wh(tmp_path):
    root = tmp_path / "warehouse"
    root.mkdir()
    return root, build_episode_warehouse(root, n=6, n_mirrored=3)


def test_cli_exports_through_prefect_cached_and_rewritten_when_damaged(prefect_api, small_wh, tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from demoforge.cli import app
    from demoforge.lib.exports.lerobot import validate_lerobot_dataset
    from demoforge.lib.exports.robomimic import read_robomimic_demo

    wh, info = small_wh
    monkeypatch.setenv("DEMOFORGE_WAREHOUSE", str(wh))
    runner = CliRunner()
    out = tmp_path / "lr"
    args = ["export", "lerobot", "--task", TASK, "--out", str(out), "--limit", "4"]
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    assert validate_lerobot_dataset(out)["episodes"] == 4
    stamp = (out / "meta/info.json").stat().st_mtime_ns
    r = runner.invoke(app, args)
    assert r.exit_code == 0 and (out / "meta/info.json").stat().st_mtime_ns == stamp  # served from the cache
    (out / "meta/stats.json").unlink()  # a damaged export is rewritten
    r = runner.invoke(app, args)
    assert r.exit_code == 0 and (out / "meta/stats.json").is_file()
    assert validate_lerobot_dataset(out)["episodes"] == 4

    h5 = tmp_path / "rm.hdf5"
    r = runner.invoke(app, ["export", "robomimic", "--task", TASK, "--out", str(h5), "--include-invalid"])
    assert r.exit_code == 0, r.output
    assert f"{sum(len(a) for a in info['actions'].values()):,} frames" in r.output
    assert read_robomimic_demo(h5, "demo_0")["attrs"]["src_kind"] == "original"

    r = runner.invoke(app, ["view", f"{TASK}/0", "--rrd", str(tmp_path / "v.rrd")])
    assert r.exit_code == 0 and (tmp_path / "v.rrd").stat().st_size > 1000, r.output
