"""Pure domain code of demoforge, one subpackage per pipeline stage; no Prefect, no warehouse layout.

- ``takes``: reading recordings (frames, depth, camera.json, annotations.json) and annotating them.
- ``perception``: hand detectors (MediaPipe, HaMeR, precomputed, the simulated detector), the hand
  model, the temporal hand tracker.
- ``ingest``: depth alignment, depth checks, the hand-to-gripper mapping, object keypoints.
- ``trajectories``: segmentation, augmentation, retrieval, query scenes, blending.
- ``task_library``: the thesis's six tasks as MuJoCo scenes with scripted demonstrations.
- ``sim``: the robot executing action sequences in MuJoCo physics; scene variations.
- ``llm``: the Appendix A prompt, its parser and the LLM backends. ``policy``: the learned policy.
- ``evaluation``: metrics, keypoint and detection evaluation, ARCTIC, real photos, plots.
- ``synth``: synthetic RGB-D takes. ``exports``: LeRobot, robomimic, Rerun.
- ``geometry``, ``joints``, ``errors``: the conventions and error kinds every stage shares.
"""

from pathlib import Path

# ../shared/data beside the checkout: the real third-party data (hand photos, an RGB-D frame).
SHARED_DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
