"""How demoforge's commands run flows (demoforge.runtime.runners.run_flow): without Prefect's flow-run
heartbeats, whose thread made every flow and subflow run end up to a second late, unless the user
asked for them."""

from __future__ import annotations

from prefect import flow
from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, get_current_settings, temporary_settings

from demoforge.runtime.runners import run_flow


@flow
def _inner() -> int | None:
    return get_current_settings().flows.heartbeat_frequency


@flow
def _outer() -> tuple[int | None, int | None]:
    return get_current_settings().flows.heartbeat_frequency, _inner()


def test_commands_run_flows_and_subflows_without_heartbeats(prefect_api, monkeypatch):
    for name in ("PREFECT_FLOWS_HEARTBEAT_FREQUENCY", "PREFECT_RUNNER_HEARTBEAT_FREQUENCY"):
        monkeypatch.delenv(name, raising=False)
    with temporary_settings(updates={PREFECT_FLOWS_HEARTBEAT_FREQUENCY: 180}):  # Prefect's default
        assert _outer() == (180, 180)  # a flow called directly keeps Prefect's setting
        assert run_flow(_outer) == (None, None)  # the flow, and its subflow, without heartbeats
        assert get_current_settings().flows.heartbeat_frequency == 180  # restored afterwards


def test_a_heartbeat_frequency_the_user_set_is_kept(prefect_api, monkeypatch):
    monkeypatch.setenv("PREFECT_FLOWS_HEARTBEAT_FREQUENCY", "60")
    with temporary_settings(updates={PREFECT_FLOWS_HEARTBEAT_FREQUENCY: 60}):  # as Prefect read it at start
        assert run_flow(_outer) == (60, 60)
