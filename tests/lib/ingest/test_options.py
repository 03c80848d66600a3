"""The option objects each declared once (demoforge.lib.ingest.options, ...augmentation.options,
demoforge.lib.evaluation.config): their checks, and their passage into the flows as a deployment's
JSON parameters would bring them."""

from __future__ import annotations

import json

import pytest

from demoforge.lib.evaluation.config import DETECTORS, EvaluateConfig
from demoforge.lib.ingest.options import IngestOptions
from demoforge.lib.trajectories.augmentation.options import AugmentOptions


@pytest.mark.parametrize("bad, message", [
    (dict(grasp_prior="rigid"), "grasp_prior must be one of pose, twist, off"),
    (dict(state_method="kmeans"), "state_method must be one of auto, otsu, threshold"),
    (dict(smoothing=-1), "smoothing must be >= 0"),
    (dict(table_clearance=-0.01), "table_clearance must be >= 0 m or None"),
])
def test_ingest_options_refuse_what_no_stage_understands(bad, message):
    with pytest.raises(ValueError, match=message):
        IngestOptions(**bad)
    assert IngestOptions(table_clearance=None).table_clearance is None  # None: the clearance is off


def test_option_objects_are_frozen_and_replace_makes_a_new_one():
    o = IngestOptions()
    with pytest.raises(AttributeError):
        o.smoothing = 3  # type: ignore[misc]
    assert o.replace(smoothing=3).smoothing == 3 and o.smoothing == 0
    a = AugmentOptions.half_mirrored(21, seed=4, mode="thesis")
    assert (a.n, a.n_mirrored, a.seed, dict(a.generation)) == (21, 10, 4, {"mode": "thesis"})
    with pytest.raises(ValueError, match="0 <= n_mirrored <= n"):
        AugmentOptions(n=10, n_mirrored=11)
    with pytest.raises(ValueError, match="n >= 1"):
        a.replace(n=0)


def test_evaluate_config_reads_lists_as_tuples_and_round_trips_through_json():
    c = EvaluateConfig(tasks=["pouring"], llm_tasks="pouring", detectors=["simulated"], llm_options={"model": "m"})
    assert c.tasks == ("pouring",) and c.llm_tasks == ("pouring",) and c.detectors == ("simulated",)
    assert EvaluateConfig().detectors == DETECTORS and EvaluateConfig().tasks is None
    d = json.loads(json.dumps(c.as_dict()))
    assert EvaluateConfig(**d) == c  # what the run key hashes rebuilds the same configuration
    with pytest.raises(ValueError, match="mirror must be both, no or yes"):
        EvaluateConfig(mirror="maybe")
    with pytest.raises(ValueError, match="trials must be >= 0"):
        EvaluateConfig(trials=-1)


def test_flows_take_the_objects_whole_and_a_deployments_json_becomes_them():
    from demoforge.flows.augment import augment_take_flow
    from demoforge.flows.evaluate import evaluate
    from demoforge.flows.ingest import ingest_take
    from demoforge.flows.ingest_folder import ingest_folder

    got = ingest_take.validate_parameters({"path": "t", "warehouse": "w",
                                           "options": {"detector": "mediapipe", "smoothing": 5}})
    assert got["options"] == IngestOptions(detector="mediapipe", smoothing=5)
    got = augment_take_flow.validate_parameters({"path": "t", "warehouse": "w", "augment": {"n": 30, "n_mirrored": 10},
                                                 "ingest": {"grasp_prior": "twist"}})
    assert got["augment"] == AugmentOptions(n=30, n_mirrored=10) and got["ingest"].grasp_prior == "twist"
    got = ingest_folder.validate_parameters({"folder": "f", "warehouse": "w", "ingest": {"detector": "simulated"},
                                             "augment": None})
    assert got["ingest"] == IngestOptions() and got["augment"] is None
    got = evaluate.validate_parameters({"warehouse": "w", "reports_dir": "r", "config": {"tasks": ["pouring"]}})
    assert got["config"] == EvaluateConfig(tasks=("pouring",))
    with pytest.raises(Exception, match="grasp_prior must be one of"):  # a bad option in JSON: refused at the door
        ingest_take.validate_parameters({"path": "t", "warehouse": "w", "options": {"grasp_prior": "x"}})
