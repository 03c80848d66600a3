"""A learned keypoint-to-trajectory policy (the thesis's future work, "a keypoint-based policy
network"): a small Transformer encoder-decoder trained on a task's augmented episode database,
predicting the same (n, 2, 8) waypoint sequences the LLM prompts ask for.

Modules: rotation6d (continuous rotation representation), data (episodes -> fixed-size training
arrays, split by placement), model (the network and its config), train (seeded training loop,
checkpoints), scenes (out-of-distribution placements, the augmentation's translation box).
No Prefect, no file layout.
"""
