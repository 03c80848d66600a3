"""The figures the report's sections name (demoforge.schemas.report_section.FIGURES), each drawn under
reports/ and returned as the Markdown lines that show it. Every figure is called with the run's
:class:`~demoforge.report.reader.ViewReader`, the reports folder and, in a PerDataset, the dataset."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from demoforge.lib.evaluation.data_scaling import plot_data_scaling
from demoforge.lib.evaluation.keypoints import plot_big_vs_small, plot_per_take_bars
from demoforge.lib.evaluation.visualize import draw_hand, draw_points, montage
from demoforge.report.episode_pictures import report_plots
from demoforge.report.reader import ViewReader


def takes_figure(reader: ViewReader, out_png: Path, columns: int = 3) -> Path | None:
    """One rendered frame per task (first grasp of its first take) with GT skeletons and object keypoints."""
    import cv2

    takes = reader.query(
        "SELECT task, take, path FROM takes WHERE NOT mirror "
        "QUALIFY row_number() OVER (PARTITION BY task ORDER BY seed) = 1 ORDER BY task").to_pylist()
    tiles, captions = [], []
    for t in takes:
        grasp = reader.query(
            "SELECT coalesce(min(frame), 0) AS f FROM gt_gripper "
            "WHERE take = ? AND closed", [t["take"]]).column("f")[0].as_py()
        frame = int(grasp) + 10
        hands = reader.query(
            "SELECT hand, joints_px, visible, present FROM gt_hand_joints "
            "WHERE take = ? AND frame = ? ORDER BY hand", [t["take"], frame]).to_pylist()
        kps = reader.query(
            "SELECT keypoints_px FROM gt_object_keypoints "
            "WHERE take = ? AND frame = ?", [t["take"], frame]).to_pylist()
        png = Path(t["path"]) / "rgb" / f"{frame:06d}.png"
        if not png.exists():
            continue
        rgb = cv2.cvtColor(cv2.imread(str(png)), cv2.COLOR_BGR2RGB)
        for h in hands:
            if h["present"]:
                rgb = draw_hand(rgb, np.array(h["joints_px"]), np.array(h["visible"]), h["hand"])
        if kps:
            rgb = draw_points(rgb, np.array(kps[0]["keypoints_px"]))
        tiles.append(rgb)
        captions.append(f"{t['task']}  frame {frame}")
    if not tiles:
        return None
    grid = montage(tiles, columns=min(columns, len(tiles)), captions=captions)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out_png), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
    return out_png


def synthetic_takes(reader: ViewReader, reports: Path) -> list[str]:
    fig = takes_figure(reader, reports / "synthetic_takes.png")
    return [f"![synthetic takes]({fig.name})" if fig else "_(no take to show)_", ""]


def detector_order(name: str) -> tuple:
    """The simulated detector first, then the real ones by name."""
    return (name != "simulated", name)


def dataset_detectors(reader: ViewReader, dataset: str) -> list[str]:
    """The detectors keypoint_metrics has rows of for ``dataset``, the simulated one first."""
    rows = reader.view("keypoint_metrics").to_pylist()
    return sorted({r["detector"] for r in rows if r["dataset"] == dataset}, key=detector_order)


def keypoints(reader: ViewReader, reports: Path, dataset: str) -> list[str]:
    """Per detector of the dataset: aligned MPJPE per take, and big vs small objects where takes have a size."""
    rows = reader.view("keypoint_metrics").to_pylist()
    md = []
    for detector in dataset_detectors(reader, dataset):
        sel = [r for r in rows if r["dataset"] == dataset and r["detector"] == detector]
        png = plot_per_take_bars(sel, "mpjpe_aligned_m", reports / f"keypoints_per_take_{dataset}_{detector}.png")
        md += [f"![aligned MPJPE per take, {detector} detector]({Path(png).name})", ""]
        if any(r.get("size_group") for r in sel):
            png = plot_big_vs_small(sel, reports / f"keypoints_big_vs_small_{dataset}_{detector}.png")
            md += [f"![big vs small objects, {detector} detector]({Path(png).name})", ""]
    return md


def data_scaling(reader: ViewReader, reports: Path) -> list[str]:
    png = plot_data_scaling(reader.view("report_data_scaling").to_pylist(), reports / "data_scaling.png")
    return [f"![closed-loop success against training episodes]({png.name})", ""] if png is not None else []


def episode_databases(reader: ViewReader, reports: Path) -> list[str]:
    return report_plots(str(reader.warehouse), str(reports))


#: Every figure a section can name, by its name in demoforge.schemas.report_section.FIGURES.
FIGURES: dict[str, Callable[..., list[str]]] = {
    "synthetic_takes": synthetic_takes,
    "keypoints": keypoints,
    "data_scaling": data_scaling,
    "episode_databases": episode_databases,
}
