"""`demoforge hamer-check` and `hamer-bench` (demoforge/cli/hamer.py) on small random weights."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from demoforge.cli import app
from demoforge.lib.perception.hamer.checkpoint import save_random_checkpoint
from demoforge.lib.perception.hamer.model import HamerConfig
from demoforge.lib.perception.hamer.synthetic import synthetic_mano, write_synthetic_mano

TINY = HamerConfig.tiny()
SIZES = json.dumps({k: v for k, v in TINY.to_dict().items() if k != "img_size"})
runner = CliRunner()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("hamer_cli")
    save_random_checkpoint(d / "hamer.ckpt", TINY)
    write_synthetic_mano(d / "MANO_RIGHT.pkl", synthetic_mano()[0])
    return d / "hamer.ckpt", d / "MANO_RIGHT.pkl"


def test_check_passes_and_runs_a_frame(files):
    ck, mano = files
    r = runner.invoke(app, ["hamer-check", "-c", str(ck), "-m", str(mano), "--sizes", SIZES, "--run", "--device", "cpu"])
    assert r.exit_code == 0, r.output
    assert "matched     75" in r.output and "missing     0" in r.output and "unexpected  0" in r.output
    assert "ignored     4" in r.output and "778 vertices" in r.output and "one frame (2 hands)" in r.output


def test_check_reports_mismatch_with_exit_2(files):
    ck, mano = files
    r = runner.invoke(app, ["hamer-check", "-c", str(ck), "-m", str(mano)])  # released sizes vs tiny file
    assert r.exit_code == 2
    assert "backbone.pos_embed: expected [1, 193, 1280], found [1, 193, 64]" in r.output
    r = runner.invoke(app, ["hamer-check", "-c", str(ck), "-m", str(mano), "--non-strict"])
    assert r.exit_code == 0


def test_check_missing_files_and_bad_sizes(files, tmp_path):
    ck, mano = files
    r = runner.invoke(app, ["hamer-check", "-c", str(tmp_path / "x.ckpt"), "-m", str(mano)])
    assert r.exit_code == 2 and "not found" in r.output
    r = runner.invoke(app, ["hamer-check", "-c", str(ck), "-m", str(tmp_path / "MANO_RIGHT.pkl"), "--sizes", SIZES])
    assert r.exit_code == 2 and "MANO model file not found" in r.output
    r = runner.invoke(app, ["hamer-check", "-c", str(ck), "-m", str(mano), "--sizes", '{"bogus": 1}'])
    assert r.exit_code == 2 and "--sizes" in r.output


def test_bench_reports_frames_per_second_per_batch_size(files):
    ck, mano = files
    r = runner.invoke(app, ["hamer-bench", "--sizes", SIZES, "--frames", "2", "-b", "1", "-b", "4", "--device", "cpu",
                            "-c", str(ck), "-m", str(mano)])
    assert r.exit_code == 0, r.output
    lines = [ln for ln in r.output.splitlines() if ln.startswith("batch")]
    assert len(lines) == 2 and all("frames/s" in ln for ln in lines)
    r = runner.invoke(app, ["hamer-bench", "--frames", "0"])
    assert r.exit_code == 2
