"""Ingest one synthetic take with a detector and print its accuracy and hand-tracking figures.

    python scripts/measure_hand_tracking.py TAKE_DIR WAREHOUSE [simulated|mediapipe]

Prints the `ingest_metrics` rows (detection fraction, aligned MPJPE, gripper errors over the frames
where the hand has a trajectory) and the `hand_presence` rows (frames detected / accepted / filled /
tracked, trusted). Used for docs/results/issue-19-hand-tracking.md.
"""

import sys
import time

from demoforge.flows.ingest import ingest_take
from demoforge.schemas.catalog import query
from demoforge.lib.ingest.options import IngestOptions

take, wh, det = sys.argv[1], sys.argv[2], (sys.argv[3] if len(sys.argv) > 3 else "simulated")
t0 = time.time()
ingest_take(take, wh, options=IngestOptions(detector=det), show_progress=False)
print("wall_s", round(time.time() - t0, 1))
for row in query("SELECT hand, detected_fraction, mpjpe_aligned_m, gripper_position_error_mm, "
                 "gripper_orientation_error_deg, open_close_acc_auto, swap_frames_injected, "
                 "swap_frames_repaired_correctly FROM ingest_metrics ORDER BY hand", wh).to_pylist():
    print(row)
for row in query("SELECT * EXCLUDE (take, task) FROM hand_presence ORDER BY hand", wh).to_pylist():
    print(row)
