"""The modules of demoforge without a mirrored test file (tests/<path>/test_<module>.py, tests/support/mirror.py),
each with the test file that covers it or the reason it has none. tests/test_architecture.py checks the table:

* ``through(test, why)``: ``test`` imports the module by name (``import demoforge.x`` / ``from demoforge.x import``)
  and exercises it; the module's tests live there (a shared fixture, a module tested with its caller).
* ``reached(test, why)``: no test imports it; ``test`` imports a module that imports it (checked on the import
  graph), and ``why`` says what of it runs there. It has no test of its own.
* ``untested(why)``: no test runs it.
* ``exempt(why)``: nothing to test: a package's docstring or re-exports, a ``python -m`` entry point, table
  declarations; such a module defines no function or class (checked).

A module that gains a mirrored file leaves the table (an entry for it fails). scripts/architecture_counts.py
counts each kind.
"""

from __future__ import annotations

from typing import NamedTuple


class Entry(NamedTuple):
    test: str | None  # a test file that imports the module and exercises it; None: no such file
    why: str  # one line: why there is no mirrored file, or why no test
    reached_by: str | None = None  # None-entries: a test that reaches it through a module it imports
    exempt: bool = False  # nothing of its own to test (no function, no class)


def through(test: str, why: str) -> Entry:
    return Entry(test, why)


def reached(test: str, why: str) -> Entry:
    return Entry(None, why, reached_by=test)


def untested(why: str) -> Entry:
    return Entry(None, why)


def exempt(why: str) -> Entry:
    return Entry(None, why, exempt=True)


TESTED_THROUGH: dict[str, Entry] = {
    # the package, entry points
    "demoforge": exempt("the package's __init__: its docstring only"),
    "demoforge.__main__": exempt("`python -m demoforge`: two lines calling the command line"),
    "demoforge.cli.__main__": exempt("`python -m demoforge.cli`: two lines calling demoforge.cli.main"),
    # bench
    "demoforge.bench": exempt("the package's docstring only"),
    "demoforge.bench.cases_warehouse": untested(
        "no test of its own: loaded by name (not on the import graph), it runs in the scratch-files test "
        "(tests/bench/test_timing.py) and `demoforge bench` (tests/cli/test_cli.py)",
    ),
    "demoforge.bench.cases_arms": untested(
        "benchmark cases: `make bench` runs them against their baselines; no test does",
    ),
    "demoforge.bench.cases_augmentation": untested(
        "benchmark cases: `make bench` runs them against their baselines; no test does",
    ),
    "demoforge.bench.cases_detection": untested(
        "benchmark cases: `make bench` runs them against their baselines; no test does",
    ),
    "demoforge.bench.cases_exports": untested(
        "benchmark cases: `make bench` runs them against their baselines; no test does",
    ),
    "demoforge.bench.cases_geometry": untested(
        "benchmark cases: `make bench` runs them against their baselines; no test does",
    ),
    "demoforge.bench.cases_hamer": untested(
        "benchmark cases: `make bench` runs them against their baselines; no test does",
    ),
    "demoforge.bench.cases_ingest": untested(
        "benchmark cases: `make bench` runs them against their baselines; no test does",
    ),
    "demoforge.bench.cases_llm": untested(
        "benchmark cases: `make bench` runs them against their baselines; no test does",
    ),
    "demoforge.bench.cases_policy": untested(
        "benchmark cases: `make bench` runs them against their baselines; no test does",
    ),
    "demoforge.bench.cases_sim": untested(
        "benchmark cases: `make bench` runs them against their baselines; no test does",
    ),
    "demoforge.bench.cases_synth": untested(
        "benchmark cases: `make bench` runs them against their baselines; no test does",
    ),
    "demoforge.bench.cases_takes": untested(
        "benchmark cases: `make bench` runs them against their baselines; no test does",
    ),
    # cli
    "demoforge.cli.benchmarks": through(
        "tests/bench/test_registry.py",
        "`demoforge bench`: its stages are the registry's (the registry's test); the command runs in "
        "tests/cli/test_cli.py",
    ),
    "demoforge.cli.capture": reached(
        "tests/lib/calibration/test_calibrate.py",
        "`convert` and `calibrate`: run through the command line by the calibration tests and "
        "tests/lib/takes/sources/test_sources.py",
    ),
    "demoforge.cli.policy": reached(
        "tests/flows/test_policy.py",
        "`train-policy`, `eval-policy`: run through the command line by the policy flow's tests",
    ),
    "demoforge.cli.screening": reached(
        "tests/lib/sim/robots/aloha/test_screening.py",
        "`screen`: its bad inputs are checked by the screening tests, through the command line",
    ),
    "demoforge.cli.table3": reached(
        "tests/flows/test_table3.py",
        "`table3`: run and its bad options checked by the Table 3 flow's tests, through the command line",
    ),
    "demoforge.cli.takes": reached(
        "tests/cli/test_cli.py",
        "`synth`, `annotate`, `ingest`, `ingest-folder`: run by the command-line smoke tests and the ingest "
        "and annotation tests",
    ),
    "demoforge.cli.variations": reached(
        "tests/cli/test_cli.py",
        "`variations`: its main path runs in the command-line smoke tests",
    ),
    "demoforge.cli.warehouse": reached(
        "tests/cli/test_cli.py",
        "`sql`, `tables`, `catalog`: run by the smoke tests and tests/schemas/test_catalog.py, through the "
        "command line",
    ),
    # envs
    "demoforge.envs.observation": through(
        "tests/envs/test_robot_env.py",
        "the observation's names and layout: checked against the export's rows by the environment's tests",
    ),
    "demoforge.envs.rollout": through(
        "tests/lib/policy/test_chunk_train.py",
        "rollout(): a bad action ending a rollout is tested with the closed-loop policy that runs it",
    ),
    # flows
    "demoforge.flows": exempt("the package's docstring only"),
    "demoforge.flows.detection_eval": untested(
        "`demoforge evaluate-detection`'s flow: no test runs it (tests/lib/evaluation/test_detection.py tests "
        "the evaluation it runs per take, and the command's refusals)",
    ),
    "demoforge.flows.ingest_folder": through(
        "tests/lib/ingest/test_options.py",
        "ingest-folder: its options (test_options.py) and its take discovery "
        "(tests/lib/takes/sources/test_sources.py, tests/runtime/test_annotate.py)",
    ),
    "demoforge.flows.screening": reached(
        "tests/flows/test_evaluate.py",
        "the screening flow: `demoforge evaluate` screens its database for the arms (test_evaluate.py); "
        "`screen`'s refusals: the screening tests",
    ),
    "demoforge.flows.view": through(
        "tests/lib/exports/test_rerun_view.py",
        "write_view(): the Rerun view of a take and of an episode, tested with the Rerun export",
    ),
    # lib (top)
    "demoforge.lib": exempt("sets MUJOCO_GL before mujoco loads and names SHARED_DATA: no functions"),
    "demoforge.lib.errors": through(
        "tests/cli/test_root.py",
        "the user-error types: which errors are the user's, and how the command line reports them",
    ),
    "demoforge.lib.joints": through(
        "tests/lib/perception/hamer/test_mano.py",
        "the hand skeleton's joint order and parents: used and checked by the MANO tests",
    ),
    "demoforge.lib.robot_spec": through(
        "tests/lib/test_registry.py",
        "the robot spec parsed once: tested with the registry it resolves names against",
    ),
    "demoforge.lib.scratch": reached(
        "tests/lib/takes/test_reader.py",
        "temporary folders removed at exit: the reader's salvaged video streams (test_reader.py) and the "
        "benchmarks' scratch files",
    ),
    "demoforge.lib.task_names": exempt(
        "the six task names as a tuple: data only (checked against the library by "
        "tests/lib/task_library/test_task_library.py)",
    ),
    # lib.annotate
    "demoforge.lib.annotate": through(
        "tests/runtime/test_annotate.py",
        "re-exports of the annotation model and task definitions, used by the annotation tests",
    ),
    "demoforge.lib.annotate.request_gate": through(
        "tests/runtime/test_annotate.py",
        "the annotation server's request gate: every route of the server is checked against it",
    ),
    # lib.calibration
    "demoforge.lib.calibration": reached(
        "tests/lib/calibration/test_calibrate.py",
        "re-exports of board, calibrate and plane (each tested in test_calibrate.py)",
    ),
    "demoforge.lib.calibration.board": through(
        "tests/lib/calibration/test_calibrate.py",
        "the ChArUco board: the printed board and its detection are part of the calibration tests",
    ),
    "demoforge.lib.calibration.plane": through(
        "tests/lib/calibration/test_calibrate.py",
        "the table plane and pose errors: the plane-and-edge calibration and frame_on_plane's property test",
    ),
    # lib.evaluation
    "demoforge.lib.evaluation": exempt("the package's docstring only"),
    "demoforge.lib.evaluation.config": through(
        "tests/lib/ingest/test_options.py",
        "the main job's config: tested with the other option objects (declared once, frozen, JSON round trip)",
    ),
    "demoforge.lib.evaluation.data_scaling": through(
        "tests/lib/evaluation/test_plots.py",
        "the data-scaling figure: tested with the other report plots",
    ),
    "demoforge.lib.evaluation.markdown": reached(
        "tests/schemas/test_reports.py",
        "the report's markdown tables: written by the report writer, whose empty-warehouse report the "
        "reports' tests check",
    ),
    "demoforge.lib.evaluation.real_photos": through(
        "tests/lib/perception/detectors/test_mediapipe_backend_real_photos.py",
        "scores on the labelled real photos: computed by the MediaPipe real-photo tests, its rows by "
        "tests/lib/evaluation/test_keypoints.py",
    ),
    "demoforge.lib.evaluation.visualize": reached(
        "tests/flows/test_ingest.py",
        "hand and gripper drawings: the ingest's overlay video (test_ingest.py) and the report's figures draw "
        "them; no test of its own",
    ),
    # lib.geometry
    "demoforge.lib.geometry": through(
        "tests/lib/geometry/test_rotations.py",
        "re-exports the geometry modules: the geometry tests call every function through it",
    ),
    "demoforge.lib.geometry._checks": reached(
        "tests/lib/geometry/test_rotations.py",
        "argument checks of the geometry functions: their errors are asserted by the geometry tests",
    ),
    "demoforge.lib.geometry.camera": reached(
        "tests/lib/exports/test_rerun_view.py",
        "pinhole projection and back-projection: used by the ingest, the exports' views and the detectors; no "
        "test of its own",
    ),
    # lib.ingest
    "demoforge.lib.ingest": exempt("the package's docstring only"),
    "demoforge.lib.ingest.gripper_open_close": through(
        "tests/lib/annotate/test_model.py",
        "the automatic open/close method: the annotation page's suggestion is checked against it",
    ),
    # lib.llm
    "demoforge.lib.llm.llama_models": reached(
        "tests/lib/llm/test_local_backend.py",
        "the embedded model's files and threads: loaded by the local backend and the reduced-vocabulary tests",
    ),
    # lib.perception
    "demoforge.lib.perception": exempt("the package's docstring only"),
    "demoforge.lib.perception.detector_registry": reached(
        "tests/lib/perception/detectors/test_detectors.py",
        "the detectors' registry: its listing and lookup are tested through "
        "demoforge.lib.perception.detectors",
    ),
    "demoforge.lib.perception.detectors.precomputed": through(
        "tests/lib/perception/detectors/test_detectors.py",
        "the precomputed backend: its round trips and errors share the detectors' synthetic take fixture",
    ),
    "demoforge.lib.perception.detectors.simulated": through(
        "tests/lib/perception/detectors/test_detectors.py",
        "the simulated backend: its swaps and misses share the detectors' synthetic take fixture",
    ),
    "demoforge.lib.perception.hamer": exempt("the package's docstring only"),
    "demoforge.lib.perception.hamer.camera": through(
        "tests/lib/perception/hamer/test_model.py",
        "HaMeR's crop camera: tested with the model (intrinsics, crops, flips)",
    ),
    "demoforge.lib.perception.hamer.checkpoint": through(
        "tests/lib/perception/hamer/test_model.py",
        "checkpoint layout and strict loading: tested with the model",
    ),
    "demoforge.lib.perception.hamer.decoder": through(
        "tests/lib/perception/hamer/test_model.py",
        "the MANO head's rot6d: tested with the model",
    ),
    "demoforge.lib.perception.hamer.synthetic": through(
        "tests/lib/perception/hamer/test_mano.py",
        "a synthetic MANO model file for the tests: written and read by the MANO tests",
    ),
    "demoforge.lib.perception.hamer.vit": reached(
        "tests/lib/perception/hamer/test_model.py",
        "the ViT backbone: runs inside the tiny model of the model tests (shapes, determinism); no test of "
        "its own",
    ),
    "demoforge.lib.perception.robust": reached(
        "tests/lib/perception/test_tracking.py",
        "robust statistics: used by the tracker and the depth alignment; no test of its own",
    ),
    "demoforge.lib.perception.track_repair": reached(
        "tests/lib/perception/test_tracking.py",
        "swap repair and gap filling: run by the tracker, whose injected swaps and drop-outs the tracking "
        "tests check",
    ),
    # lib.policy
    "demoforge.lib.policy": exempt("the package's docstring only"),
    "demoforge.lib.policy.checkpoints": reached(
        "tests/lib/policy/test_train.py",
        "checkpoint files: the round trips of test_train.py and test_chunk_train.py go through it",
    ),
    "demoforge.lib.policy.chunking": through(
        "tests/lib/policy/test_chunk_train.py",
        "temporal ensembling of action chunks: tested with the chunk policy that uses it",
    ),
    "demoforge.lib.policy.joint_demos": through(
        "tests/lib/policy/test_chunk_train.py",
        "the arms' joint-space demonstrations: the chunk policy's training data, tested there",
    ),
    "demoforge.lib.policy.model": through(
        "tests/lib/policy/test_train.py",
        "the keypoint policy network: its shape checks are tested with training",
    ),
    # lib.sim
    "demoforge.lib.sim": through(
        "tests/lib/sim/test_executor.py",
        "re-exports the simulator (execute, SimOptions, ...) and render_episode: the executor's tests use "
        "them",
    ),
    "demoforge.lib.sim.failures": through(
        "tests/envs/test_robot_env.py",
        "the failure classes: the environment's verdicts are checked against them (and the executor's pinned "
        "verdicts)",
    ),
    "demoforge.lib.sim.gripper": through(
        "tests/envs/test_robot_env.py",
        "the parallel gripper's model: the environment's close commands are checked against it",
    ),
    "demoforge.lib.sim.loop": reached(
        "tests/lib/sim/test_executor.py",
        "the one frame loop that execute, the stepper and the replay run: exercised by their tests, no test "
        "of its own",
    ),
    "demoforge.lib.sim.options": reached(
        "tests/envs/test_robot_env.py",
        "sim_options by robot name: used by the environments and the flows; no test of its own",
    ),
    "demoforge.lib.sim.scene": through(
        "tests/lib/sim/test_replay.py",
        "the compiled scene cache: the replay keeps its MJCF's physics (test_replay.py); the executor checks "
        "physics options",
    ),
    "demoforge.lib.sim.stepper": through(
        "tests/envs/test_robot_env.py",
        "a frame at a time for the environments: the env runs execute's physics bit for bit",
    ),
    "demoforge.lib.sim.variation_scene": through(
        "tests/lib/sim/test_variations.py",
        "the varied scene (distractors, resized objects): tested with the variations",
    ),
    # lib.sim.robots
    "demoforge.lib.sim.robots": through(
        "tests/lib/sim/robots/aloha/test_aloha.py",
        "the robot registry (get_robot, choices): tested with the arms",
    ),
    "demoforge.lib.sim.robots.base": reached(
        "tests/lib/sim/test_replay.py",
        "the robot interface: implemented by the grippers, the arms and the replay's hands; no test of its "
        "own",
    ),
    "demoforge.lib.sim.robots.grippers": reached(
        "tests/lib/sim/test_executor.py",
        "the floating grippers: the executor's pinned verdicts are theirs",
    ),
    "demoforge.lib.sim.robots.hands": reached(
        "tests/lib/sim/test_replay.py",
        "the demonstrator's welded mocap hands: what the replay runs",
    ),
    "demoforge.lib.sim.robots.ik": through(
        "tests/lib/sim/robots/aloha/test_closed_form.py",
        "the IK helpers: the closed form's wrist branches are checked with them",
    ),
    "demoforge.lib.sim.robots.retarget": reached(
        "tests/lib/sim/robots/aloha/test_aloha.py",
        "object-centric retargeting: the arms' executions of the scripted demonstrations go through it; no "
        "test of its own",
    ),
    "demoforge.lib.sim.robots.aloha.grasp_choice": reached(
        "tests/lib/sim/robots/aloha/test_screening.py",
        "the grasp turn chosen per window: part of the screening, whose verdicts are pinned",
    ),
    "demoforge.lib.sim.robots.aloha.model": through(
        "tests/lib/sim/robots/aloha/test_aloha.py",
        "the arms' model (bases, rest pose): used by every arm test",
    ),
    "demoforge.lib.sim.robots.aloha.placement": through(
        "tests/lib/sim/robots/aloha/test_closed_form.py",
        "the arms' base placement per task: the closed form is checked at those bases",
    ),
    "demoforge.lib.sim.robots.aloha.retargeting": reached(
        "tests/lib/sim/robots/aloha/test_aloha.py",
        "the arms' grasps of their own: the scripted demonstrations' arm verdicts depend on it",
    ),
    "demoforge.lib.sim.robots.aloha.screening_pairs": reached(
        "tests/lib/sim/robots/aloha/test_screening.py",
        "the two arms' forearm pair checks: part of the screening, whose verdicts are pinned",
    ),
    "demoforge.lib.sim.robots.aloha.seeds": through(
        "tests/lib/sim/robots/aloha/test_closed_form.py",
        "per-pose IK seeds: the closed form is checked equal to them",
    ),
    # lib.synth
    "demoforge.lib.synth": reached(
        "tests/flows/test_synth.py",
        "mirror_flags and lazy attribute access: used by the synth flow and command; no test of its own",
    ),
    # lib.takes
    "demoforge.lib.takes": through(
        "tests/lib/takes/test_reader.py",
        "re-exports the take reader (open_take, read_frame, ...): the reader's tests use it",
    ),
    "demoforge.lib.takes.convert": reached(
        "tests/lib/takes/sources/test_sources.py",
        "`demoforge convert`: a recording converted to a take folder in the take sources' tests",
    ),
    "demoforge.lib.takes.media": reached(
        "tests/lib/takes/test_reader.py",
        "image and video decoding: the reader's bad-media tests go through it",
    ),
    "demoforge.lib.takes.metadata": reached(
        "tests/lib/takes/test_reader.py",
        "camera.json and annotations.json parsing: the reader's bad-input tests go through it",
    ),
    "demoforge.lib.takes.pose": reached(
        "tests/lib/calibration/test_calibrate.py",
        "a recording's camera pose file: written when the annotate page calibrates a recording "
        "(test_calibrate.py)",
    ),
    "demoforge.lib.takes.thesis_json": reached(
        "tests/lib/takes/test_reader.py",
        "the thesis's keypoint JSON: read by the reader's and the precomputed detector's tests",
    ),
    "demoforge.lib.takes.types": reached(
        "tests/lib/takes/test_reader.py",
        "the take's types (Take, TakeError, ...): used by every take test",
    ),
    "demoforge.lib.takes.sources.base": reached(
        "tests/lib/takes/sources/test_sources.py",
        "the take source interface: implemented by every source the sources' tests open",
    ),
    "demoforge.lib.takes.sources.folder": through(
        "tests/lib/takes/test_reader.py",
        "the take folder and MP4 sources: what the reader's tests open and damage",
    ),
    "demoforge.lib.takes.sources.record3d": reached(
        "tests/lib/takes/sources/test_sources.py",
        "Record3D recordings: opened and ingested by the take sources' tests",
    ),
    "demoforge.lib.takes.sources.recording": through(
        "tests/lib/takes/sources/test_sources.py",
        "the RealSense SDK recording source: tested with the other sources",
    ),
    "demoforge.lib.takes.sources.rosbag2": through(
        "tests/lib/takes/sources/test_sources.py",
        "ROS 2 bags: tested with the other sources (topics chosen and remembered)",
    ),
    "demoforge.lib.takes.sources.writers": through(
        "tests/lib/takes/sources/test_sources.py",
        "writes recordings in each source's format: how the sources' tests make their recordings",
    ),
    # lib.task_library
    "demoforge.lib.task_library.base": through(
        "tests/lib/task_library/test_task_library.py",
        "the task interface (mirroring, replay, faults): the task library's tests",
    ),
    "demoforge.lib.task_library.objects": through(
        "tests/lib/sim/test_variations.py",
        "object models: resized by the variations, checked against their geometry there",
    ),
    "demoforge.lib.task_library.scripting": reached(
        "tests/lib/task_library/test_task_library.py",
        "how the scripted takes move: every scripted demonstration the library's tests replay is made here",
    ),
    "demoforge.lib.task_library.tasks": reached(
        "tests/lib/task_library/test_task_library.py",
        "the six tasks: what the task library's tests compile, script and replay",
    ),
    # lib.trajectories
    "demoforge.lib.trajectories": exempt("the package's docstring only"),
    "demoforge.lib.trajectories.augmentation": through(
        "tests/lib/trajectories/augmentation/test_generate.py",
        "re-exports the augmentation's modules: its tests call them through it",
    ),
    "demoforge.lib.trajectories.augmentation.options": through(
        "tests/lib/ingest/test_options.py",
        "AugmentOptions: tested with the other option objects",
    ),
    # report
    "demoforge.report": exempt("the package's docstring only"),
    "demoforge.report.episode_pictures": through(
        "tests/lib/evaluation/test_plots.py",
        "the report's plots of real episodes: tested with the plots they draw",
    ),
    "demoforge.report.figures": through(
        "tests/schemas/test_reports.py",
        "the figures the writer knows: checked against the reports' declarations",
    ),
    "demoforge.report.reader": through(
        "tests/schemas/test_reports.py",
        "reading the report views once per run: tested with the reports' declarations",
    ),
    "demoforge.report.writer": through(
        "tests/schemas/test_reports.py",
        "REPORT.md in report order: tested with the reports' declarations",
    ),
    # runtime
    "demoforge.runtime": exempt("the package's docstring only"),
    "demoforge.runtime.artifacts": reached(
        "tests/flows/test_evaluate.py",
        "Prefect artifacts the flows publish: made by the flows' runs; no test of its own",
    ),
    "demoforge.runtime.provenance": reached(
        "tests/schemas/test_reports.py",
        "run provenance stamps: written into the report and the benchmarks; no test of its own",
    ),
    "demoforge.runtime.run_cache": through(
        "tests/tasks/test_common.py",
        "the whole-run cache of `demoforge evaluate`: tested with the stages' cache keys",
    ),
    # schemas
    "demoforge.schemas": through(
        "tests/schemas/test_reports.py",
        "imports every contract module (registers the tables): the reports' tests read the registry",
    ),
    "demoforge.schemas.column_types": through(
        "tests/schemas/test_core.py",
        "column types of the contracts: tested with the contracts",
    ),
    "demoforge.schemas.contracts": through(
        "tests/schemas/test_core.py",
        "table declarations and the registry: tested with the contracts' writer and reader",
    ),
    "demoforge.schemas.files": reached(
        "tests/schemas/test_core.py",
        "one file: atomic write, hash, damaged-file error: the contracts' atomic-write tests go through it",
    ),
    "demoforge.schemas.migrations": reached(
        "tests/schemas/test_catalog.py",
        "migrations of older files: the catalog's version tests and test_core.py's depth-coverage migration "
        "run them",
    ),
    "demoforge.schemas.validation": through(
        "tests/schemas/test_core.py",
        "validation naming the column: tested with the contracts",
    ),
    "demoforge.schemas.warehouse": through(
        "tests/schemas/test_core.py",
        "the warehouse layout, reader and writer: tested with the contracts",
    ),
    "demoforge.schemas.augment": exempt(
        "table contracts and views only (declarations): every contract is checked by "
        "tests/schemas/test_core.py",
    ),
    "demoforge.schemas.benchmarks": exempt(
        "table contracts only (declarations): every contract is checked by tests/schemas/test_core.py",
    ),
    "demoforge.schemas.closed_loop": exempt(
        "table contracts and views only (declarations): every contract is checked by "
        "tests/schemas/test_core.py",
    ),
    "demoforge.schemas.detection": exempt(
        "table contracts only (declarations): every contract is checked by tests/schemas/test_core.py",
    ),
    "demoforge.schemas.ingest": through(
        "tests/schemas/test_core.py",
        "the ingest's contracts and their migration: the depth-coverage migration is tested there",
    ),
    "demoforge.schemas.ingested_demos": exempt(
        "table contracts and views only (declarations): every contract is checked by "
        "tests/schemas/test_core.py",
    ),
    "demoforge.schemas.keypoints": exempt(
        "table contracts and views only (declarations): every contract is checked by "
        "tests/schemas/test_core.py",
    ),
    "demoforge.schemas.llm": exempt(
        "table contracts only (declarations): every contract is checked by tests/schemas/test_core.py",
    ),
    "demoforge.schemas.policy": exempt(
        "table contracts and views only (declarations): every contract is checked by "
        "tests/schemas/test_core.py",
    ),
    "demoforge.schemas.screening": exempt(
        "table contracts only (declarations): every contract is checked by tests/schemas/test_core.py",
    ),
    "demoforge.schemas.synthetic": through(
        "tests/lib/synth/test_take.py",
        "the synthetic takes' ground-truth contracts: every GT table a take writes validates against them",
    ),
    "demoforge.schemas.takes": exempt(
        "table contracts only (declarations): every contract is checked by tests/schemas/test_core.py",
    ),
    "demoforge.schemas.variations": through(
        "tests/flows/test_variations.py",
        "the variations' contracts and Table 4 views: the flow's test queries them",
    ),
    "demoforge.schemas.sim": reached(
        "tests/schemas/test_catalog.py",
        "the simulation's contracts, views and their migrations: the catalog's sim_results version tests",
    ),
    "demoforge.schemas.table3": reached(
        "tests/flows/test_table3.py",
        "Table 3's contracts and report views: the grid's test reads them",
    ),
    "demoforge.schemas.reads": exempt("the package's docstring only"),
    "demoforge.schemas.reads.demonstration": reached(
        "tests/flows/test_table3.py",
        "an ingested take's demonstration source: read by the Table 3 grid and the augment flow; no test of "
        "its own",
    ),
    "demoforge.schemas.reads.episodes": through(
        "tests/lib/exports/test_lerobot.py",
        "episode databases read back: the exports' tests load what they export",
    ),
    "demoforge.schemas.reads.per_hand": through(
        "tests/flows/test_ingest_hand_tracking.py",
        "per-hand arrays of the ingest's tables: read by the hand-tracking acceptance tests",
    ),
    "demoforge.schemas.report_section": through(
        "tests/schemas/test_reports.py",
        "the report's sections as data: tested with the reports' declarations",
    ),
    # tasks
    "demoforge.tasks": exempt("re-exports only (and Prefect's settings from demoforge's defaults, at import)"),
    "demoforge.tasks.augment": through(
        "tests/flows/test_augment.py",
        "the augment stage: the flow's test regenerates episodes through it",
    ),
    "demoforge.tasks.closed_loop": reached(
        "tests/flows/test_closed_loop.py",
        "the closed-loop stages: run by the data-scaling flow's test",
    ),
    "demoforge.tasks.detection_eval": untested(
        "the detection evaluation's stage: no test runs it (only `demoforge evaluate-detection` does)",
    ),
    "demoforge.tasks.export": through(
        "tests/lib/exports/test_lerobot.py",
        "the export stages: the exports' tests call them",
    ),
    "demoforge.tasks.ingest": reached(
        "tests/flows/test_ingest.py",
        "the ingest stages: run by the ingest flow's tests (and take_media_key by the sources' tests)",
    ),
    "demoforge.tasks.ingest_drawing": reached(
        "tests/flows/test_ingest.py",
        "the overlay video: drawn by the ingest flow's overlay test",
    ),
    "demoforge.tasks.ingest_evaluation": reached(
        "tests/flows/test_ingest.py",
        "the ingest's accuracy metrics: checked by the ingest flow's accuracy test",
    ),
    "demoforge.tasks.keypoint_eval": reached(
        "tests/flows/test_keypoint_eval.py",
        "the keypoint evaluation's stages: run by its flow's tests",
    ),
    "demoforge.tasks.policy": through(
        "tests/flows/test_policy.py",
        "the policy stages: the policy flow's test loads their data",
    ),
    "demoforge.tasks.screening": through(
        "tests/lib/sim/robots/aloha/test_screening.py",
        "the screening stage: its table and database are read back by the screening tests",
    ),
    "demoforge.tasks.sim": reached(
        "tests/flows/test_sim.py",
        "the simulation stages: run by the simulate flow's tests",
    ),
    "demoforge.tasks.synth": reached("tests/flows/test_synth.py", "the synthesis stage: run by the synth flow's tests"),
    "demoforge.tasks.table3": through(
        "tests/end_to_end/test_screening_consumers.py",
        "Table 3's database: the screened-in episodes it keeps (the grid itself: tests/flows/test_table3.py)",
    ),
    "demoforge.tasks.variations": through(
        "tests/test_architecture.py",
        "the variations' cache keys (code_files): checked to exist; the stage runs in "
        "tests/flows/test_variations.py",
    ),
}
