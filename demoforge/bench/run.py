"""`make bench`: every stage's benchmark against its baseline, written to `warehouse/benchmarks`."""

from __future__ import annotations

import secrets
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from prefect import flow, get_run_logger

from demoforge.bench.timing import BenchCase, BenchResult, run_case
from demoforge.runtime.provenance import git_commit, machine_info
from demoforge.lib.scratch import folder_removed_at_exit
from demoforge.schemas.core import Column, TableSchema, keypoints3d, registry, write_table

# Each stage registers a function quick -> list[BenchCase] here.
CASE_FACTORIES: dict[str, Callable[[bool], list[BenchCase]]] = {}


def register(stage: str) -> Callable:
    def deco(factory: Callable[[bool], list[BenchCase]]) -> Callable[[bool], list[BenchCase]]:
        CASE_FACTORIES[stage] = factory
        return factory

    return deco


# Not registered: a scratch table for the benchmark only, so it never shows in the catalog.
_SCRATCH = TableSchema("_bench_keypoints", 1, "warehouse benchmark scratch table", (
    Column("frame", pa.int64(), "row index"), Column("joints", keypoints3d(21), "random joints")))


@register("warehouse")
def _warehouse_cases(quick: bool) -> list[BenchCase]:
    rows = 20_000 if quick else 200_000

    def setup(n: int):
        rng = np.random.default_rng(0)
        joints = rng.normal(size=(n, 21, 3))
        frame = np.arange(n, dtype=np.int64)
        tmp = folder_removed_at_exit("demoforge-bench-")

        def fast():
            return write_table(_SCRATCH, {"frame": frame, "joints": joints}, tmp / "fast")

        def baseline():
            # What one writes without the vectorised conversion: Python lists row by row.
            t = pa.table({"frame": frame.tolist(), "joints": [j.tolist() for j in joints]})
            t = t.cast(pa.schema([("frame", pa.int64()), ("joints", pa.list_(pa.list_(pa.float64(), 3), 21))]))
            (tmp / "base").mkdir(exist_ok=True)
            pq.write_table(t, tmp / "base" / "data.parquet", compression="zstd")
            return t.num_rows

        return fast, baseline

    def catalog_setup(n: int):
        from demoforge.schemas import catalog

        root = folder_removed_at_exit("demoforge-bench-") / "warehouse"

        def views(path: Path) -> list[tuple[str, str]]:
            import duckdb

            con = duckdb.connect(str(path), read_only=True)
            try:
                return con.execute("SELECT view_name, sql FROM duckdb_views() WHERE NOT internal AND "
                                   "view_name <> '_catalog' ORDER BY view_name").fetchall()
            finally:
                con.close()

        def fast():
            return views(catalog.build_catalog(root))

        def fresh_types(schema: TableSchema) -> list[str]:
            import duckdb

            con = duckdb.connect()
            try:
                return [str(t) for t in con.from_arrow(schema.arrow.empty_table()).types]
            finally:
                con.close()

        def baseline():
            # what every build did before: a new DuckDB connection per contract to learn its column types
            cached, catalog._duckdb_types = catalog._duckdb_types, fresh_types
            try:
                return views(catalog.build_catalog(root))
            finally:
                catalog._duckdb_types = cached

        return fast, baseline

    def same_views(a, b):
        assert a == b, "the catalog's views differ"

    return [
        BenchCase("warehouse", "validate+atomic write, 21x3 keypoints", rows, "rows",
                  "per-row Python lists -> pyarrow -> Parquet, no validation", setup),
        BenchCase("warehouse", "catalog rebuild (a view per contract)", len(registry()), "views",
                  "the same build with a new DuckDB connection per contract for its column types", catalog_setup,
                  check=same_views),
    ]


@register("geometry")
def _geometry_cases(quick: bool) -> list[BenchCase]:
    from demoforge.lib import geometry as g

    n = 20_000 if quick else 200_000

    def close(a, b):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-9)

    def quat_setup(k):
        q = g.random_quaternions(k, np.random.default_rng(1))

        def baseline():  # per-quaternion formula in Python
            out = np.empty((k, 3, 3))
            for i, (x, y, z, w) in enumerate(q):
                out[i] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                          [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                          [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
            return out

        return (lambda: g.quat_to_matrix(q)), baseline

    def rodrigues_setup(k):
        rng = np.random.default_rng(2)
        a, b = rng.normal(size=(k, 3)), rng.normal(size=(k, 3))

        def baseline():  # the thesis's formula, one pair at a time
            out = np.empty((k, 3, 3))
            for i in range(k):
                ah, bh = a[i] / np.linalg.norm(a[i]), b[i] / np.linalg.norm(b[i])
                v = np.cross(ah, bh)
                vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
                out[i] = np.eye(3) + vx + vx @ vx * (1 - ah @ bh) / (v @ v)
            return out

        return (lambda: g.rotation_between_vectors(a, b)), baseline

    def umeyama_setup(k):
        rng = np.random.default_rng(3)
        src = rng.normal(size=(k, 21, 3))
        R = g.random_rotations(k, rng)
        dst = 1.3 * np.einsum("kij,knj->kni", R, src) + rng.normal(size=(k, 1, 3))

        def baseline():  # one SVD per sample in a Python loop
            out = np.empty((k, 3, 3))
            for i in range(k):
                _, Ri, _ = g.umeyama(src[i], dst[i])
                out[i] = Ri
            return out

        return (lambda: g.umeyama(src, dst)[1]), baseline

    def reflect_setup(k):
        rng = np.random.default_rng(4)
        p8 = np.concatenate([rng.normal(size=(k, 2, 3)), g.random_quaternions(2 * k, rng).reshape(k, 2, 4),
                             np.ones((k, 2, 1))], axis=-1)

        def baseline():  # matrix route, one pose at a time
            out = np.empty_like(p8)
            M = np.diag([-1.0, 1.0, 1.0])
            for i in range(k):
                for a in range(2):
                    T, grip = g.pose8_to_transform(p8[i, a])
                    R = M @ T[:3, :3]
                    R[:, 1] *= -1
                    out[i, a] = g.transform_to_pose8(g.make_transform(R, M @ T[:3, 3]), grip)
            return out

        def fast():
            return g.reflect_pose8(p8)

        return fast, baseline

    def same_rotation_pose8(a, b):
        a, b = np.asarray(a), np.asarray(b)
        close(a[..., :3], b[..., :3])
        close(g.quat_to_matrix(a[..., 3:7]), g.quat_to_matrix(b[..., 3:7]))

    small = max(n // 20, 1000)
    return [
        BenchCase("geometry", "quat_to_matrix", n, "quats", "per-quaternion Python formula", quat_setup,
                  close, baseline_size=small),
        BenchCase("geometry", "rotation_between_vectors (Rodrigues)", n, "pairs",
                  "thesis formula per pair in a Python loop", rodrigues_setup, close, baseline_size=small),
        BenchCase("geometry", "umeyama 21-point similarity", n // 10, "samples",
                  "one SVD per sample in a Python loop", umeyama_setup, close, baseline_size=small // 10),
        BenchCase("geometry", "reflect_pose8 across YZ (2-arm poses)", n // 2, "steps",
                  "matrix route per pose in a Python loop", reflect_setup, same_rotation_pose8,
                  baseline_size=small // 2),
    ]


@register("synth")
def _synth_cases(quick: bool) -> list[BenchCase]:
    frames = 10 if quick else 40

    def setup(n: int):
        import mujoco

        from demoforge.lib.perception.hand_model import hand_from_pinch
        from demoforge.lib.synth.render import SceneRenderer, extra_worldbody_xml, hands_assets_xml
        from demoforge.lib.synth.take import hand_styles_for
        from demoforge.lib.task_library import get_task

        task = get_task("pouring")
        demo = task.scripted_demo(0)
        styles = hand_styles_for(0)
        xml = task.scene_xml(demo.placement, extra_worldbody=extra_worldbody_xml(styles),
                             extra_assets=hands_assets_xml(styles))
        idx = np.linspace(0, demo.n_frames - 1, n).astype(int)
        joints = np.stack([hand_from_pinch(demo.pinch_poses[idx, h], demo.aperture[idx, h],
                                           ("left", "right")[h], styles[h])[0] for h in range(2)], 1)
        ours = SceneRenderer(xml, task.object_names, styles)
        naive = SceneRenderer(xml, task.object_names, styles, multisamples=4)
        scn = naive._renderer.scene
        scn.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = True
        scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = True
        scn.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = True

        def run(renderer):
            def go():
                depth_sum = 0.0
                for k, i in enumerate(idx):
                    renderer.set_state(demo.object_poses[i], joints[k])
                    depth_sum += float(renderer.render().depth.sum())
                return depth_sum
            return go

        return run(ours), run(naive)

    def setup_write(n: int):
        from demoforge.lib.synth.take import generate_take

        root = folder_removed_at_exit("demoforge-bench-take-")
        generate_take("pouring", 0, False, root / "warm-up", max_frames=2)  # imports, EGL, codecs: untimed

        def run(queue: int):
            def go():
                out = root / f"q{queue}"
                generate_take("pouring", 0, False, out, max_frames=n, write_queue=queue)
                return out
            return go

        return run(4), run(0)

    def same_files(ours: Path, baseline: Path) -> None:
        import filecmp

        for sub in ("rgb", "depth"):
            names = sorted(p.name for p in (ours / sub).iterdir())
            match, mismatch, errors = filecmp.cmpfiles(ours / sub, baseline / sub, names, shallow=False)
            assert not mismatch and not errors, f"{sub}: {mismatch or errors} differ from the serial writer's"
        assert filecmp.cmp(ours / "rgb.mp4", baseline / "rgb.mp4", shallow=False), "rgb.mp4 differs"

    return [BenchCase("synth", "render RGB-D 640x480 (pouring scene)", frames, "frames",
                      "MuJoCo defaults: shadows, reflections, skybox, 4x multisampling", setup, repeats=1),
            BenchCase("synth", "write a take (render + noise + PNG/.npy/MP4, pouring)", frames, "frames",
                      "each frame written before the next renders (write_queue=0)", setup_write,
                      check=same_files, repeats=1)]


@register("ingest")
def _ingest_cases(quick: bool) -> list[BenchCase]:
    from demoforge.bench.cases_ingest import cases

    return cases(quick)


@register("augmentation")
def _augmentation_cases(quick: bool) -> list[BenchCase]:
    from demoforge.bench.cases_augmentation import cases

    out = [c for c in cases(quick) if c.stage == "augmentation"]
    n = 2_000 if quick else 10_000

    def write_setup(k: int):
        from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes
        from demoforge.lib.task_library import get_task
        from demoforge.tasks.augment import episode_steps_columns

        task = get_task("empty_vase")
        batch = generate_episodes(from_scripted_demo(task, task.scripted_demo(0)), n=k - 1,
                                  n_mirrored=(k - 1) // 2, seed=0, materialize=True)
        tmp = folder_removed_at_exit("demoforge-bench-")

        def fast():
            return write_table("episode_steps", episode_steps_columns("empty_vase", "bench", batch), tmp)[0].rows

        def baseline():  # one Python row per step, then pyarrow and Parquet
            rows = [{"task": "empty_vase", "take": "bench", "episode_id": int(e), "step": s,
                     "action": batch.actions[e, s].astype(np.float32).tolist()}
                    for e in range(len(batch)) for s in range(int(batch.lengths[e]))]
            (tmp / "base").mkdir(exist_ok=True)
            pq.write_table(pa.Table.from_pylist(rows), tmp / "base" / "data.parquet")
            return len(rows)

        return fast, baseline

    out.append(BenchCase("augmentation", "write episode_steps of 10k episodes (validated, atomic)", n + 1 if not quick else n,
                         "episodes", "one Python dict per step -> pyarrow -> Parquet", write_setup,
                         repeats=1, baseline_size=200))
    return out


@register("retrieval")
def _retrieval_cases(quick: bool) -> list[BenchCase]:
    from demoforge.bench.cases_augmentation import cases

    return [c for c in cases(quick) if c.stage == "retrieval"]


@register("sim")
def _sim_cases(quick: bool) -> list[BenchCase]:
    from demoforge.bench.cases_sim import cases

    return cases(quick)


@register("arms")
def _arms_cases(quick: bool) -> list[BenchCase]:
    from demoforge.bench.cases_arms import cases

    return cases(quick)


@flow(name="benchmarks", log_prints=True)
def run_benchmarks(warehouse: str, stages: Iterable[str] | None = None, quick: bool = False) -> list[dict]:
    """Run the benchmark cases of the given stages (all by default) and append them to `benchmarks`."""
    logger = get_run_logger()
    wanted = list(stages) if stages else list(CASE_FACTORIES)
    unknown = [s for s in wanted if s not in CASE_FACTORIES]
    if unknown:
        raise ValueError(f"unknown benchmark stage(s) {unknown}; known: {sorted(CASE_FACTORIES)}")
    run_id = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ") + "-" + secrets.token_hex(3)
    machine, commit = machine_info(), git_commit(str(Path(__file__).resolve().parents[1]))
    results: list[BenchResult] = []
    for stage in wanted:
        for case in CASE_FACTORIES[stage](quick):
            logger.info("bench %s / %s (%d %s)", case.stage, case.name, case.size, case.unit)
            results.append(run_case(case))
    now = datetime.now(timezone.utc)
    rows = [
        {
            "run_id": run_id, "stage": r.stage, "case_name": r.case, "size": r.size, "unit": r.unit,
            "seconds": r.seconds, "baseline_seconds": r.baseline_seconds, "ratio": r.ratio,
            "items_per_second": r.items_per_second, "baseline": r.baseline, "repeats": r.repeats,
            "machine": machine, "git_commit": commit, "measured_at": now,
        }
        for r in results
    ]
    if rows:
        write_table("benchmarks", pa.Table.from_pylist(rows), warehouse)
    return rows


@register("detection")
def _detection_cases(quick: bool) -> list[BenchCase]:
    from demoforge.bench.cases_detection import cases

    return cases(quick)


@register("hamer")
def _hamer_cases(quick: bool) -> list[BenchCase]:
    from demoforge.bench.cases_hamer import cases

    return cases(quick)


@register("exports")
def _exports_cases(quick: bool) -> list[BenchCase]:
    from demoforge.bench.cases_exports import cases

    return cases(quick)


@register("policy")
def _policy_cases(quick: bool) -> list[BenchCase]:
    from demoforge.bench.cases_policy import cases

    return cases(quick)


@register("llm")
def _llm_cases(quick: bool) -> list[BenchCase]:
    from demoforge.bench.cases_llm import cases

    return cases(quick)
