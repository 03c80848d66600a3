"""Evaluation of demoforge's stages against ground truth: code that measures how well a stage did
(detection of hands on synthetic takes, ...) and returns plain rows for the warehouse tables of
``schemas/``. The older keypoint evaluation (thesis Tables 1-2) lives in lib/keypoint_eval.py."""
