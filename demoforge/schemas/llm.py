"""The `llm_trials` table: one row per prediction trial (thesis 4.3.1 / Table 3)."""

import pyarrow as pa

from demoforge.schemas.core import Column, keypoints3d, table

LLM_TRIALS = table(
    "llm_trials",
    version=1,
    doc=("One prediction for one query scene: the prompt strategy's examples, the backend's answer, the "
         "parsed action sequence, and its MuJoCo success check. LLM-free baselines have backend `none`."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "Source take of the task database the examples come from."),
        Column("trial", pa.int32(), "Query scene number (the scene is drawn from `seed` and this number)."),
        Column("strategy", pa.string(), "`single` (the original demo), `random` (3 random episodes), `retrieval` (top-3 keypoint MSE); baselines `replay_top1` (the top-1 episode itself) and `transform_demo` (the demo transformed to the scene)."),
        Column("backend", pa.string(), "`local` (Gemma 3 270M, llama.cpp), `openai` (an OpenAI-compatible endpoint) or `none`."),
        Column("model", pa.string(), "Model name (empty for `none`)."),
        Column("seed", pa.int64(), "Seed of the query scenes and of the random strategy."),
        Column("query_keypoints", keypoints3d(11), "The query scene's 11 object keypoints, world frame, m."),
        Column("retrieved_episode_ids", pa.list_(pa.int64()), "Episodes used as examples (or replayed)."),
        Column("n_waypoints", pa.int32(), "Action rows the answer is asked for: the uniform waypoint count, or the keyframe count of the most similar example (keyframe prompts)."),
        Column("prompt_tokens", pa.int32(), "Prompt length in the backend's tokens (0 for `none`)."),
        Column("answer_tokens", pa.int32(), "Answer length in tokens."),
        Column("latency_s", pa.float64(), "Wall time of the prediction, s (0 when served from the answer cache)."),
        Column("cached", pa.bool_(), "The answer came from the answer cache."),
        Column("parse_status", pa.string(), "`ok`, `truncated`, `empty`, `no_array`, `wrong_shape`, `non_finite`, `zero_quaternion`, or `llm_error`."),
        Column("parse_detail", pa.string(), "What the parser or the backend said."),
        Column("success", pa.bool_(), "The predicted trajectory succeeded in the MuJoCo check (false when it could not be parsed)."),
        Column("failure_reason", pa.string(), "The simulator's failure class, or the parse status; empty on success."),
        Column("sim_detail", pa.string(), "The simulator's explanation (task predicate, collisions)."),
        Column("prompt_hash", pa.string(), "sha256 of the prompt (the answer cache key includes it)."),
        Column("raw_answer", pa.string(), "The backend's answer as returned."),
    ],
    partition_by=("task", "take", "strategy"),
)
