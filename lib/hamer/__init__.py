"""HaMeR in torch, from a local checkpoint: the thesis's simplified hand detector (issue 11).

* :mod:`lib.hamer.vit` - ViT-H/16 backbone (ViTPose layout), :mod:`lib.hamer.decoder` - the MANO
  transformer-decoder head; together :class:`lib.hamer.model.HamerNet`, whose state_dict keys and
  shapes are the released ``hamer.ckpt``'s (``backbone.*``, ``mano_head.*``).
* :mod:`lib.hamer.checkpoint` - safe reading of the Lightning checkpoint, the strict key check.
* :mod:`lib.hamer.mano` - MANO forward kinematics in torch from the user's MANO_RIGHT.pkl.
* :mod:`lib.hamer.camera` - crops (left hands flipped), the crop camera moved to the real intrinsics.
* :mod:`lib.hamer.model` - :class:`HamerPredictor`: batched inference, CPU or CUDA, kept loaded.
* :mod:`lib.hamer.backend` - the ``hamer`` :class:`lib.detectors.HandDetector` (boxes from the
  previous frame's keypoints or from MediaPipe).
* :mod:`lib.hamer.synthetic` - a MANO-like model for tests and benchmarks (no licensed files).

Neither the checkpoint nor the MANO model is downloaded by demoforge: both are licensed.
"""

from lib.hamer.model import HamerConfig, HamerNet, HamerPredictor, HandPrediction  # noqa: F401
