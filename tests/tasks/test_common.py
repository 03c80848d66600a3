"""The cache convention on a real Prefect flow: content-keyed, code-versioned, output-checked."""

from pathlib import Path

import pyarrow as pa
import pyarrow.csv as pacsv
import pytest
from prefect import flow

from demoforge.schemas.core import Column, read_table, table, write_table
from demoforge.tasks.common import ContentHashPolicy, Manifest, content_fingerprint, run_stage, stage_task
from tests.support.paths import REPO_ROOT

table("_test_counts", 1, "word counts of a text file (cache test)", [
    Column("word", pa.string(), "a word"),
    Column("count", pa.int64(), "occurrences"),
])

CALLS = {"n": 0}


def _count_words(text_file: Path, warehouse: str, min_count: int = 1) -> Manifest:
    CALLS["n"] += 1
    words = text_file.read_text().split()
    counts = {w: words.count(w) for w in sorted(set(words)) if words.count(w) >= min_count}
    written = write_table("_test_counts", {"word": list(counts), "count": list(counts.values())}, warehouse)
    return Manifest.from_written("_test_counts", written, Path(warehouse) / "_test_counts")


count_words_v1 = stage_task(name="count_words", version="1")(_count_words)
count_words_v2 = stage_task(name="count_words", version="2")(_count_words)


@flow(name="count-words")
def count_flow(text_file: str, warehouse: str, version: int = 1, min_count: int = 1) -> Manifest:
    stage = count_words_v1 if version == 1 else count_words_v2
    return run_stage(stage, warehouse, text_file=Path(text_file), warehouse=warehouse, min_count=min_count)


@pytest.fixture()
def text_file(tmp_path):
    f = tmp_path / "input.txt"
    f.write_text("pour pour cup bottle pour cup")
    return f


def test_second_run_is_served_from_cache_and_input_change_invalidates(prefect_api, warehouse, text_file):
    CALLS["n"] = 0
    m1 = count_flow(str(text_file), str(warehouse))
    assert CALLS["n"] == 1 and m1.rows == 3
    m2 = count_flow(str(text_file), str(warehouse))
    assert CALLS["n"] == 1, "second run with identical input must come from the cache"
    assert m2 == m1
    assert (warehouse / "_prefect" / "results").is_dir()

    text_file.write_text("pour cup")  # content changes: recompute
    m3 = count_flow(str(text_file), str(warehouse))
    assert CALLS["n"] == 2 and m3.rows == 2 and m3.content_hash != m1.content_hash
    counts = dict(zip(*read_table("_test_counts", warehouse).to_pydict().values()))
    assert counts == {"cup": 1, "pour": 1}

    count_flow(str(text_file), str(warehouse), min_count=2)  # a parameter change: recompute
    assert CALLS["n"] == 3


def test_code_version_salt_invalidates(prefect_api, warehouse, text_file):
    CALLS["n"] = 0
    count_flow(str(text_file), str(warehouse), version=1)
    count_flow(str(text_file), str(warehouse), version=1)
    assert CALLS["n"] == 1
    count_flow(str(text_file), str(warehouse), version=2)
    assert CALLS["n"] == 2


def test_deleted_output_is_recomputed_not_served_stale(prefect_api, warehouse, text_file):
    CALLS["n"] = 0
    m1 = count_flow(str(text_file), str(warehouse))
    Path(m1.files[0]).unlink()
    m2 = count_flow(str(text_file), str(warehouse))
    assert CALLS["n"] == 2 and Path(m2.files[0]).is_file() and m2.is_intact()


def test_touching_a_file_without_changing_content_keeps_the_key(tmp_path):
    f = tmp_path / "a.txt"
    f.write_text("same")
    policy = ContentHashPolicy(salt="s@1")
    k1 = policy.compute_key(None, {"f": f}, {})
    f.write_text("same")
    assert policy.compute_key(None, {"f": f}, {}) == k1
    f.write_text("diff")
    assert policy.compute_key(None, {"f": f}, {}) != k1
    assert ContentHashPolicy(salt="s@2").compute_key(None, {"f": f}, {}) != policy.compute_key(None, {"f": f}, {})


def test_unhashable_inputs_are_refused_with_advice():
    import numpy as np

    with pytest.raises(TypeError, match="pathlib.Path"):
        content_fingerprint({"arr": np.zeros(3)})


def test_folder_digests_are_remembered_across_processes_and_follow_changes(tmp_path, monkeypatch):
    """A take folder is hashed once; a later process (the in-process memo cleared) only stats it, and a
    changed file is hashed again and changes the key."""
    import demoforge.tasks.common as common

    monkeypatch.setenv("DEMOFORGE_DIGEST_CACHE", str(tmp_path / "digests"))
    take = tmp_path / "take"
    (take / "rgb").mkdir(parents=True)
    for i in range(3):
        (take / "rgb" / f"{i:06d}.png").write_bytes(bytes([i]) * 1000)
    (take / "camera.json").write_text('{"fx": 1}')
    first = content_fingerprint(take)
    assert len(list((tmp_path / "digests").glob("*.json"))) == 1

    hashed = []
    real = common.file_sha256
    monkeypatch.setattr(common, "file_sha256", lambda p: hashed.append(Path(p).name) or real(p))
    monkeypatch.setattr(common, "_FILE_HASH_MEMO", {})  # as in a new process
    assert content_fingerprint(take) == first and hashed == []
    (take / "rgb" / "000001.png").write_bytes(b"other pixels")
    changed = content_fingerprint(take)
    assert changed != first and hashed == ["000001.png"]
    # the same content as a fresh folder elsewhere (no record yet) gives the same key
    monkeypatch.setattr(common, "_FILE_HASH_MEMO", {})
    import shutil

    shutil.copytree(take, tmp_path / "copy" / "take")
    assert content_fingerprint(tmp_path / "copy" / "take") == changed


def test_a_progress_bar_never_changes_a_stage_key():
    """The main job ingests a take with a progress bar and the side-by-side ingest again without one:
    one key, so the second call is a cache hit instead of rewriting the take's hand_keypoints."""
    import importlib
    import inspect
    import pkgutil

    import demoforge.tasks as tasks_pkg

    checked = []
    for mod_info in pkgutil.iter_modules(tasks_pkg.__path__):
        mod = importlib.import_module(f"demoforge.tasks.{mod_info.name}")
        for obj in vars(mod).values():
            policy = getattr(obj, "cache_policy", None)
            if not isinstance(policy, ContentHashPolicy) or "show_progress" not in inspect.signature(obj.fn).parameters:
                continue
            inputs = {"x": 1, "show_progress": True}
            assert policy.compute_key(None, inputs, {}) == policy.compute_key(None, {**inputs, "show_progress": False}, {}), obj.name
            checked.append(obj.name)
    assert "detect_hands" in checked and "synthesize_take" in checked, checked


def test_the_whole_run_key_sees_every_source_file_of_the_package(tmp_path):
    """`demoforge evaluate`'s run-level cache (demoforge.runtime.run_cache) must change its key when any
    source of the run changes; a fingerprint of no files would serve an old report after an update."""
    import shutil

    from demoforge.runtime import run_cache

    root = REPO_ROOT
    want = {"demoforge": root / "demoforge", **{f"demoforge.{p}": root / "demoforge" / p
                                                for p in ("lib", "tasks", "flows", "schemas")}}
    assert run_cache.code_dirs() == want
    # a copy laid out like a checkout: demoforge/ with the dependency pins beside it
    shutil.copytree(root / "demoforge", tmp_path / "checkout" / "demoforge", ignore=shutil.ignore_patterns("__pycache__"))
    copy = {name: tmp_path / "checkout" / folder.relative_to(root) for name, folder in want.items()}
    shutil.copytree(root / "requirements", tmp_path / "checkout" / "requirements")
    shutil.copy(root / "pyproject.toml", tmp_path / "checkout")
    before = run_cache.code_fingerprint(copy)
    assert before == run_cache.code_fingerprint(want)  # the content counts, not where it lies
    geometry = copy["demoforge.lib"] / "geometry" / "__init__.py"
    geometry.write_text(geometry.read_text() + "\n# changed\n")
    assert run_cache.code_fingerprint(copy) != before
    with pytest.raises(RuntimeError, match="no source files"):
        run_cache.code_fingerprint({"demoforge.lib": tmp_path / "empty"})
