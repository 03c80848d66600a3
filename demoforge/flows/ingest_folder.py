"""The `ingest-folder` flow: every take under a folder, each ingested (and augmented on request) on its
own, failures recorded per take (`folder_ingests`)."""

from __future__ import annotations

from pathlib import Path
from prefect import flow, get_run_logger

from demoforge.flows.augment import augment_take_flow
from demoforge.flows.ingest import ingest_take
from demoforge.lib.annotate import annotation_status, not_annotated_message
from demoforge.lib.ingest.options import IngestOptions
from demoforge.lib.takes.sources import find_takes
from demoforge.lib.trajectories.augmentation.options import AugmentOptions
from demoforge.runtime.runners import run_flow
from demoforge.schemas.core import write_table
from demoforge.tasks.common import opened_take


def find_take_folders(folder: str | Path) -> list[Path]:
    """Takes under ``folder`` (any depth), sorted by path: folders holding a camera.json and recordings
    (demoforge.lib.takes.sources.find_takes)."""
    root = Path(folder)
    if not root.is_dir():
        raise ValueError(f"{root}: no such folder to ingest takes from")
    return find_takes(root)


@flow(name="ingest-folder")
def ingest_folder(
    folder: str,
    warehouse: str,
    task: str | None = None,
    ingest: IngestOptions | None = None,
    augment: AugmentOptions | None = None,
    show_progress: bool = False,
) -> list[dict]:
    """Ingest every take folder under `folder` (the scheduled deployment's flow).

    A take is a folder with camera.json (layout: README 'Take folders'). Takes already ingested are
    served from the cache, so running this on a schedule only processes new or changed takes. A take
    that fails is recorded in `folder_ingests` with the reason and does not stop the others.
    A take without object-keypoint annotations is ingested up to its gripper poses and recorded as
    `needs_annotation` (its episodes wait for `demoforge annotate`).
    ingest: how each take is ingested (IngestOptions; default: the simulated detector). With `augment`
    (AugmentOptions), each annotated take also gets its episode database.
    """
    import pyarrow as pa

    logger = get_run_logger()
    opts = ingest or IngestOptions()
    folder_abs = Path(folder).resolve()
    takes = find_take_folders(folder_abs)
    logger.info("%d take folder(s) under %s", len(takes), folder_abs)
    rows = []
    for take_dir in takes:
        row = {"folder": str(folder_abs), "take": take_dir.name if take_dir.is_dir() else take_dir.name.split(".")[0],
               "path": str(take_dir), "detector": opts.detector,
               "status": "ingested", "error": "", "gripper_rows": 0, "episodes": 0}
        try:
            status = annotation_status(opened_take(take_dir))  # the flows it runs get this take
            if augment is not None and status.annotated:
                out = run_flow(augment_take_flow, str(take_dir), warehouse, task=task, augment=augment, ingest=opts,
                               show_progress=show_progress)
                row["episodes"] = int(out["episodes"].rows)
            else:
                out = run_flow(ingest_take, str(take_dir), warehouse, task=task, options=opts,
                               show_progress=show_progress)
            row["gripper_rows"] = int(out["gripper_poses"].rows)
            if out.get("object_keypoints") is None:
                row.update(status="needs_annotation", error=not_annotated_message(take_dir, status.detail))
        except Exception as e:  # noqa: BLE001  (one bad take must not stop the folder)
            row.update(status="failed", error=f"{type(e).__name__}: {e}"[:2000])
            logger.warning("take %s failed: %s", take_dir.name, row["error"])
        write_table("folder_ingests", pa.Table.from_pylist([row]), warehouse)
        rows.append(row)
    failed = sum(r["status"] == "failed" for r in rows)
    waiting = sum(r["status"] == "needs_annotation" for r in rows)
    logger.info("ingested %d take(s), %d need annotation, %d failed (see the folder_ingests table)",
                len(rows) - failed - waiting, waiting, failed)
    return rows
