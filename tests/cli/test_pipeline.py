"""`demoforge evaluate` (demoforge/cli/pipeline.py): --free and --number-format (or their environment variables)
reach the main job's config; a bad number format is one line."""

from __future__ import annotations


def test_evaluate_passes_structured_and_number_format_to_its_flow(monkeypatch, tmp_path):
    from typer.testing import CliRunner

    from demoforge.cli import app

    seen = []

    def fake_run_flow(flow, warehouse, reports_dir, config):
        seen.append(config)
        raise ValueError("stop here")

    monkeypatch.setattr("demoforge.cli.pipeline.run_flow", fake_run_flow)
    base = ["--warehouse", str(tmp_path), "evaluate", "--fresh", "--detector", "simulated"]
    for args, env in [(["--free", "--number-format", "compact"], {}), ([], {"DEMOFORGE_LLM_NUMBER_FORMAT": "thesis"})]:
        r = CliRunner().invoke(app, base + args, env=env)
        assert r.exit_code != 0 and "stop here" in r.output, r.output
    assert [(c.llm_structured, c.llm_number_format) for c in seen] == [(False, "compact"), (None, "thesis")]
    r = CliRunner().invoke(app, base + ["--number-format", "hex"])
    assert r.exit_code == 2 and "--number-format must be one of" in r.output and "Traceback" not in r.output
