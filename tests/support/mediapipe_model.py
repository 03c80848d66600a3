"""The MediaPipe hand model the detector tests need, or a skip that says how to provide it."""

import pytest


def require_mediapipe_model():
    """Skip, saying how to provide it, when the MediaPipe package or its hand-landmarker model file is
    absent; once both are there, every error of the detector is the test's to report."""
    pytest.importorskip("mediapipe", reason="mediapipe is not installed: pip install --no-deps -r "
                        "requirements/mediapipe.txt (make setup does)")
    from demoforge.lib.perception.detectors.mediapipe_backend import MODEL_ENV, default_model_path

    path = default_model_path()
    if not path.is_file():
        pytest.skip(f"MediaPipe hand model {path} absent: build it with `.venv/bin/python "
                    f"scripts/fetch_mediapipe_model.py` (make setup does) or point ${MODEL_ENV} at a .task file")
    return path

