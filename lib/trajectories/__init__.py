"""Trajectory pieces: segmentation, augmentation, retrieval, keyframe encoding, query scenes.

Pure numpy over whole demonstrations and episode batches; no Prefect, no file layout.
"""
