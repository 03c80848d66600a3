"""The fixed 21-joint hand order (MediaPipe/OpenPose) and its graphs: the one place they are defined."""

import numpy as np

N_JOINTS = 21
JOINT_NAMES = (
    "wrist",
    "thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip",
    "index_mcp", "index_pip", "index_dip", "index_tip",
    "middle_mcp", "middle_pip", "middle_dip", "middle_tip",
    "ring_mcp", "ring_pip", "ring_dip", "ring_tip",
    "pinky_mcp", "pinky_pip", "pinky_dip", "pinky_tip",
)
FINGER_NAMES = ("thumb", "index", "middle", "ring", "pinky")
FINGER_JOINTS = ((1, 2, 3, 4), (5, 6, 7, 8), (9, 10, 11, 12), (13, 14, 15, 16), (17, 18, 19, 20))
THUMB_TIP, INDEX_TIP = 4, 8

#: Kinematic tree: parent of each joint (-1 for the wrist); every finger hangs off the wrist.
PARENTS = np.array([-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 0, 13, 14, 15, 0, 17, 18, 19])

#: Skeleton edges for drawing and capsules (parent, child): MediaPipe's HAND_CONNECTIONS,
#: which also closes the palm (index MCP - middle MCP - ring MCP - pinky MCP).
HAND_CONNECTIONS: tuple[tuple[int, int], ...] = (
    (0, 1), (1, 2), (2, 3), (3, 4),
    (0, 5), (5, 6), (6, 7), (7, 8),
    (5, 9), (9, 10), (10, 11), (11, 12),
    (9, 13), (13, 14), (14, 15), (15, 16),
    (13, 17), (0, 17), (17, 18), (18, 19), (19, 20),
)
