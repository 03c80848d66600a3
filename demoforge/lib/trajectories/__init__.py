"""Trajectory pieces: motion/skill segmentation (``segmentation``), the 10,000-episode augmentation
(``augmentation``), top-k retrieval by object-keypoint MSE (``retrieval``), query scenes drawn like
the database (``query_scenes``), the top-k blend (``blend``) and the keyframe encoding of action
sequences (``keyframes``).

Pure numpy over whole demonstrations and episode batches; no Prefect, no file layout.
"""
