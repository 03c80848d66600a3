"""HaMeR in torch, from a local checkpoint: the thesis's simplified hand detector (issue 11).

* :mod:`demoforge.lib.perception.hamer.vit` - ViT-H/16 backbone (ViTPose layout), :mod:`demoforge.lib.perception.hamer.decoder` - the MANO
  transformer-decoder head; together :class:`demoforge.lib.perception.hamer.model.HamerNet`, whose state_dict keys and
  shapes are the released ``hamer.ckpt``'s (``backbone.*``, ``mano_head.*``).
* :mod:`demoforge.lib.perception.hamer.checkpoint` - safe reading of the Lightning checkpoint, the strict key check.
* :mod:`demoforge.lib.perception.hamer.mano` - MANO forward kinematics in torch from the user's MANO_RIGHT.pkl.
* :mod:`demoforge.lib.perception.hamer.camera` - crops (left hands flipped), the crop camera moved to the real intrinsics.
* :mod:`demoforge.lib.perception.hamer.model` - :class:`HamerPredictor`: batched inference, CPU or CUDA, kept loaded.
* :mod:`demoforge.lib.perception.hamer.backend` - the ``hamer`` :class:`demoforge.lib.perception.detectors.HandDetector` (boxes from the
  previous frame's keypoints or from MediaPipe).
* :mod:`demoforge.lib.perception.hamer.synthetic` - a MANO-like model for tests and benchmarks (no licensed files).

Neither the checkpoint nor the MANO model is downloaded by demoforge: both are licensed.
"""

from demoforge.lib.perception.hamer.model import (  # noqa: F401
    HamerConfig, HamerNet, HamerPredictor, HandPrediction,
)
