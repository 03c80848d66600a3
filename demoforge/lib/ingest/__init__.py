"""Ingest, after detection: the thesis's depth correction at anchor joints (``alignment``), the
checks that stop a take whose depth cannot be trusted (``depth_checks``), the hand-to-gripper
mapping with open/close (``gripper_mapping``), and object keypoints from annotated pixels and depth
(``object_keypoints``). Reading the take itself is :mod:`demoforge.lib.takes`."""
