"""llm_predict (demoforge.tasks.llm_eval) without Prefect: examples ordered most similar last, keyframe answers
decoded with the keyframe decoder, uniform answers upsampled, structured answers asked of the local backend by
default."""

from __future__ import annotations

import numpy as np

from demoforge.lib.llm import FakeBackend, get_backend
from demoforge.lib.llm.prompting import format_actions, format_keypoints
from demoforge.lib.trajectories.keyframes import DEFAULT_KEYFRAMES, keyframe_actions, reconstruction_error, smooth_actions
from demoforge.tasks.llm_eval import llm_predict
from tests.support.llm import demo, hand_episode


def _examples():
    """Three episodes of 40 steps (a query at shift 0.01: the nearest is shift 0.0, then -0.04, 0.08)."""
    return [hand_episode(0.0, n=40), hand_episode(0.08, n=40), hand_episode(-0.04, n=40)]


def test_keyframe_answer_is_decoded_on_the_nearest_examples_time_curve():
    exs = _examples()
    q = hand_episode(0.01, n=40)
    seen = []

    def copy_nearest(prompt, sampling):
        # a model that copies the last example's action block (the thesis saw GPT do that)
        seen.append(prompt)
        return prompt.user.split("** New Input **")[0].split("Action Sequence:\n")[-1].split("\n# shape")[0]

    actions, fields = llm_predict(get_backend("fake", responses=copy_nearest), exs, q.keypoints, q.initial,
                                  n_steps=40, n_waypoints=None)
    prompt = seen[0]
    assert prompt.encoding == "keyframes" and fields["parse_status"] == "ok", fields["parse_detail"]
    # the nearest example (lowest keypoint MSE) is written last, the farthest first
    demos = prompt.user.split("** New Input **")[0]
    assert format_keypoints(exs[0].keypoints) in demos.split("** Demo 2 **")[1]
    assert format_keypoints(exs[1].keypoints) in demos.split("** Demo 1 **")[0]
    assert prompt.n_waypoints == len(keyframe_actions(exs[0].actions, DEFAULT_KEYFRAMES)[1])
    # decoded to the episode length, within the encoding's tolerance of the smoothed sequence it encodes
    # (+ the prompt's 3-decimal rounding)
    assert actions.shape == (40, 2, 8)
    dp, dq = reconstruction_error(smooth_actions(exs[0].actions, DEFAULT_KEYFRAMES.smooth_sigma_steps), actions)
    assert dp.max() < DEFAULT_KEYFRAMES.pos_tol_m + 1e-3 and dq.max() < DEFAULT_KEYFRAMES.rot_tol_rad + 2e-3
    assert np.array_equal(actions[:, :, 7], exs[0].actions[:, :, 7])  # open/close at the same steps


def test_uniform_answers_still_upsampled():
    exs = _examples()
    q = hand_episode(0.01, n=40)
    from demoforge.lib.llm.prompting import resample_actions

    good = format_actions(resample_actions(exs[0].actions, 6))
    actions, fields = llm_predict(get_backend("fake", responses=[good]), exs, q.keypoints, q.initial, n_steps=40,
                                  n_waypoints=6)
    assert fields["parse_status"] == "ok" and fields["parse_detail"] == "" and actions.shape == (40, 2, 8)
    bad, fields = llm_predict(get_backend("fake", responses=["no"]), exs, q.keypoints, q.initial, n_steps=40)
    assert bad is None and fields["parse_status"] == "no_array"


def test_llm_predict_asks_for_structured_answers_by_default_only_from_the_local_backend():
    from demoforge.tasks.llm_eval import llm_predict

    class LocalLike(FakeBackend):
        name = "local"

    ex = demo(n=4)
    for cls, structured, expected in ((LocalLike, None, True), (FakeBackend, None, False),
                                      (LocalLike, False, False), (FakeBackend, True, True)):
        got = []
        b = cls(lambda p, s: got.append(s.structured) or "")
        llm_predict(b, [ex], ex[0] + 0.01, ex[1], n_steps=20, n_waypoints=2, structured=structured)
        assert got == [expected], (cls.__name__, structured)
