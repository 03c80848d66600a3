"""The measuring commands' LLM options (demoforge/cli/evaluation.py, and table3's alike): --free, --backend,
--base-url, --model and --api-mode reach the flow."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize("command, module", [("llm-eval", "demoforge.cli.evaluation"), ("table3", "demoforge.cli.table3")])
def test_structured_and_base_url_flags_reach_the_flow(command, module, monkeypatch, tmp_path):
    from typer.testing import CliRunner

    from demoforge.cli import app

    seen = []

    def fake_run_flow(flow, warehouse, **kwargs):
        seen.append(kwargs)
        raise ValueError("stop here")

    monkeypatch.setattr(f"{module}.run_flow", fake_run_flow)
    base = ["--warehouse", str(tmp_path), command, "--task", "pouring"]
    openai = ["--backend", "openai", "--base-url", "http://127.0.0.1:9/v1", "--model", "m", "--api-mode", "completions"]
    runs = [(base + openai + ["--free"], {}), (base + openai, {"DEMOFORGE_LLM_STRUCTURED": "1"}),
            (base + ["--backend", "local"], {"DEMOFORGE_LLM_STRUCTURED": None})]
    for args, env in runs:
        r = CliRunner().invoke(app, args, env=env)
        assert r.exit_code != 0 and "stop here" in r.output, r.output
    assert [k["structured"] for k in seen] == [False, True, None]  # None: the default (on for local)
    assert seen[0]["backend_options"] == {"mode": "completions", "model": "m", "base_url": "http://127.0.0.1:9/v1"}
    assert seen[2]["backend_options"] == {}
