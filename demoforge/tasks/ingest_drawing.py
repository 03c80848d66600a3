"""The ingest's optional drawing: the take's video with the corrected hand skeletons and the gripper frames."""

from __future__ import annotations

from pathlib import Path

from demoforge.lib.evaluation.visualize import draw_gripper, draw_hand
from demoforge.lib.ingest.alignment import project
from demoforge.lib.takes import iter_frames, take_task_name
from demoforge.schemas.core import file_sha256, read_table
from demoforge.schemas.reads.per_hand import HANDS, arrays
from demoforge.tasks.common import Manifest, opened_take, stage_task
from demoforge.tasks.ingest import INGEST_VERSION


@stage_task(name="overlay_video", version=INGEST_VERSION, key_optional=("variant",))
def overlay_video(take_dir: Path, task: str | None, warehouse: str, aligned: Manifest,
                  grippers: Manifest, variant: dict | None = None) -> Manifest:
    """An MP4 of the take with the corrected hand skeletons and the gripper frames drawn on the RGB
    frames (like the GIFs of the thesis's public code): warehouse/videos/<take>.<detector>.mp4."""
    import cv2

    take = opened_take(take_dir)
    name = take_task_name(take, task)
    part = dict(task=name, take=take.take_id, variant=variant)
    al_t = read_table("aligned_keypoints", warehouse, **part)
    T, al = arrays(al_t, "joints_cam", "present")
    _, gp = arrays(read_table("gripper_poses", warehouse, **part), "pose")
    detector = al_t.column("detector")[0].as_py()
    px = project(al["joints_cam"], take.K)
    out_dir = Path(warehouse) / "videos"
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / f"{take.take_id}.{detector}.mp4"
    tmp = out_dir / f".{target.name}.tmp.mp4"
    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(take.fps),
                             (take.camera.width, take.camera.height))
    frames = 0
    try:
        for batch in iter_frames(take, batch_size=16):
            for i, rgb in zip(batch.indices, batch.rgb):
                for h, side in enumerate(HANDS):
                    if al["present"][i, h]:
                        rgb = draw_hand(rgb, px[i, h], side=side)
                    rgb = draw_gripper(rgb, gp["pose"][i, h], take.K, take.camera.T_world_camera, label=side[0].upper())
                writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
                frames += 1
    finally:
        writer.release()
    tmp.replace(target)
    return Manifest("overlay_video", str(target), frames, file_sha256(target), (str(target),))
