"""Table contracts (demoforge.schemas.core, whose names come from its modules: contracts, column_types,
validation, warehouse, files, migrations): validation names the column, writes are atomic, reads check the version."""

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from demoforge.schemas.column_types import dual_pose8, keypoints3d
from demoforge.schemas.contracts import SchemaError, TableSchema, get_schema, registry
from demoforge.schemas.validation import validate
from demoforge.schemas.warehouse import read_table, table_files, write_table
from tests.support.poses_table import pose_rows  # registers the _test_poses table


def test_round_trip_keeps_values_and_fixed_shapes(tmp_path):
    data = pose_rows()
    written = write_table("_test_poses", data, tmp_path)
    assert len(written) == 1 and written[0].rows == 4
    assert written[0].path.endswith("_test_poses/take=t1/data.parquet")
    back = read_table("_test_poses", tmp_path)
    assert back.schema.field("joints").type == keypoints3d(21)
    np.testing.assert_array_equal(np.array(back.column("joints").to_pylist()), data["joints"])
    np.testing.assert_array_equal(np.array(back.column("action").to_pylist()), data["action"])
    meta = pq.read_schema(written[0].path).metadata
    assert meta[b"demoforge.schema_version"] == b"3"
    assert b"joints, m" in pq.read_schema(written[0].path).field("joints").metadata[b"doc"]


def test_partitions_are_written_and_replaced_independently(tmp_path):
    write_table("_test_poses", pose_rows(3, "a"), tmp_path)
    write_table("_test_poses", pose_rows(5, "b"), tmp_path)
    write_table("_test_poses", pose_rows(2, "a", seed=1), tmp_path)  # replaces partition a only
    assert read_table("_test_poses", tmp_path, take="a").num_rows == 2
    assert read_table("_test_poses", tmp_path, take="b").num_rows == 5
    assert read_table("_test_poses", tmp_path).num_rows == 7


@pytest.mark.parametrize(
    "column, bad, message",
    [
        ("joints", np.zeros((4, 20, 3)), "'joints'"),
        ("joints", np.zeros((4, 21, 2)), "'joints'"),
        ("frame", ["x", "y", "z", "w"], "'frame'"),
        ("action", np.zeros((4, 2, 7)), "'action'"),
        ("frame", [1.5, 2.0, 3.0, 4.0], "'frame'"),
    ],
)
def test_wrong_type_or_shape_names_the_column_and_leaves_previous_file(tmp_path, column, bad, message):
    (good,) = write_table("_test_poses", pose_rows(), tmp_path)
    before = open(good.path, "rb").read()
    data = pose_rows()
    data[column] = bad
    with pytest.raises(SchemaError, match=message):
        write_table("_test_poses", data, tmp_path)
    assert open(good.path, "rb").read() == before
    leftovers = [p for p in (tmp_path / "_test_poses").rglob("*") if p.is_file() and p.name != "data.parquet"]
    assert leftovers == []


def test_missing_extra_and_null_columns_are_refused(tmp_path):
    data = pose_rows()
    del data["score"]
    with pytest.raises(SchemaError, match=r"missing column\(s\) \['score'\]"):
        validate("_test_poses", data)
    data = pose_rows()
    data["extra"] = [1] * 4
    with pytest.raises(SchemaError, match="unexpected column"):
        validate("_test_poses", data)
    data = pose_rows()
    data["take"] = ["t", None, "t", "t"]
    with pytest.raises(SchemaError, match="'take'.*null"):
        validate("_test_poses", data)
    data = pose_rows()
    data["score"] = [None] * 4  # nullable column accepts nulls
    assert validate("_test_poses", data).column("score").null_count == 4


def test_nan_is_a_value_but_a_missing_coordinate_is_refused():
    data = pose_rows()
    joints = [[[0.0, 0.0, 0.0]] * 21 for _ in range(4)]
    joints[2][5] = [0.0, None, 0.0]
    data["joints"] = joints
    with pytest.raises(SchemaError, match="'joints'.*null element"):
        validate("_test_poses", data)


def test_failed_write_mid_file_keeps_previous_version(tmp_path, monkeypatch):
    (good,) = write_table("_test_poses", pose_rows(), tmp_path)
    before = open(good.path, "rb").read()

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(pq, "write_table", boom)
    with pytest.raises(OSError, match="disk full"):
        write_table("_test_poses", pose_rows(seed=9), tmp_path)
    assert open(good.path, "rb").read() == before
    assert [p.name for p in (tmp_path / "_test_poses" / "take=t1").iterdir()] == ["data.parquet"]


def test_reader_refuses_other_schema_version(tmp_path):
    write_table("_test_poses", pose_rows(), tmp_path)
    schema = get_schema("_test_poses")
    (f,) = table_files("_test_poses", tmp_path)
    t = pq.read_table(f)
    pq.write_table(t.replace_schema_metadata({b"demoforge.schema_version": b"2"}), f)
    with pytest.raises(SchemaError, match="version 2.*version 3"):
        read_table("_test_poses", tmp_path)
    assert schema.version == 3


def test_unsafe_partition_value_is_refused(tmp_path):
    with pytest.raises(SchemaError, match="partition column 'take'"):
        write_table("_test_poses", pose_rows(take="../escape"), tmp_path)


def test_reading_an_unwritten_table_gives_an_empty_typed_table(tmp_path):
    t = read_table("_test_poses", tmp_path)
    assert t.num_rows == 0 and t.schema.field("action").type == dual_pose8()


def test_every_registered_table_documents_every_column():
    for name, schema in registry().items():
        assert isinstance(schema, TableSchema) and schema.version >= 1
        for c in schema.columns:
            assert len(c.doc) > 3, f"{name}.{c.name} is undocumented"
        assert "| column |" in schema.describe()


def test_partitioned_write_of_a_sliced_nested_list_table_keeps_the_right_rows(tmp_path):
    """pyarrow 26.0.1 filters a sliced nested fixed-size-list array wrongly; the writer must not."""
    import numpy as np
    import pyarrow as pa

    from demoforge.schemas.core import read_table, write_table

    n = 12
    action = np.arange(n * 16, dtype=np.float32).reshape(n, 2, 8)
    full = pa.table({
        "task": ["pouring"] * n, "take": ["a"] * 6 + ["b"] * 6,
        "episode_id": pa.array(np.arange(n), pa.int64()), "step": pa.array(np.zeros(n), pa.int32()),
        "action": pa.FixedSizeListArray.from_arrays(
            pa.FixedSizeListArray.from_arrays(pa.array(action.ravel()), 8), 2).cast(
            pa.list_(pa.list_(pa.float32(), 8), 2)),
    })
    sliced = full.slice(3)  # rows 3..11, partitions a (3 rows) and b (6 rows)
    write_table("episode_steps", sliced, tmp_path)
    back = read_table("episode_steps", tmp_path).sort_by("episode_id")
    got = np.asarray(back.column("action").to_pylist(), np.float32)
    assert back.column("episode_id").to_pylist() == list(range(3, n))
    np.testing.assert_array_equal(got, action[3:])


def test_a_warehouse_of_the_previous_ingest_contracts_gains_the_depth_coverage_columns(tmp_path):
    """hand_presence and ingest_metrics v1 files (before the depth coverage columns): the catalog's
    migration gives them the columns, NaN (not measured then), instead of every query failing to bind."""
    import demoforge.schemas.ingest  # noqa: F401  (registers the tables and their migrations)
    from demoforge.schemas.catalog import query
    from demoforge.schemas.core import get_schema, read_table

    schema = get_schema("hand_presence")
    new = ("depth_missing_fraction", "depth_missing_frame_fraction")
    old = pa.schema([f for f in schema.arrow if f.name not in new],
                    metadata={**schema.arrow.metadata, b"demoforge.schema_version": b"1"})
    row = {f.name: {pa.string(): "x", pa.int32(): 3, pa.bool_(): True}[f.type] for f in old}
    f = tmp_path / "hand_presence" / "task=pouring" / "take=old" / "data.parquet"
    f.parent.mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist([{**row, "hand": "left"}], schema=old), f)
    got = query("SELECT hand, frames, depth_missing_fraction AS d, depth_missing_frame_fraction AS fd "
                "FROM hand_presence", tmp_path).to_pylist()
    assert len(got) == 1 and got[0]["hand"] == "left" and got[0]["frames"] == 3
    assert np.isnan(got[0]["d"]) and np.isnan(got[0]["fd"])
    assert read_table("hand_presence", tmp_path).num_rows == 1      # now in the current contract
