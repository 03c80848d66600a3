"""Table contracts: one versioned pyarrow schema per warehouse table, one validating writer, one reader.

Every table in the warehouse is declared once with :func:`table` (name, version, columns with their
units and frames, partition columns). :func:`write_table` is the only way anything is written to the
warehouse: it checks the data against the contract, refuses a mismatch with an error naming the
column, and replaces the partition's file atomically (temporary file in the same folder, fsync,
``os.replace``), so a reader never sees a half-written file and a failed write leaves the previous
file untouched.

This module is the public face of the contracts; each job lives in its own module:
:mod:`.contracts` (declaration and registry), :mod:`.column_types`, :mod:`.validation`,
:mod:`.files` (one file: atomic write, hash, damaged-file error), :mod:`.warehouse` (layout, partitions,
variants, table reader and writer), :mod:`.migrations`.
"""

from demoforge.schemas.column_types import dual_pose8, fixed_list, keypoints2d, keypoints3d, matrix4, pose8, vec3
from demoforge.schemas.contracts import Column, SchemaError, TableSchema, get_schema, metric_column, registry, table
from demoforge.schemas.files import (WarehouseDamaged, WrittenFile, atomic_write_parquet, damaged_file_error,
                                     file_sha256, parquet_metadata, read_parquet_file, read_table_file,
                                     write_table_file)
from demoforge.schemas.migrations import added_columns_migration, migrate_warehouse, register_migration
from demoforge.schemas.validation import column_numpy, validate
from demoforge.schemas.warehouse import (ALL_VARIANTS, DATA_FILE, partition_dir, read_table, table_files,
                                         unsliced_table, variant_parts, write_table)

__all__ = [
    "ALL_VARIANTS", "Column", "DATA_FILE", "SchemaError", "TableSchema", "WarehouseDamaged", "WrittenFile",
    "added_columns_migration", "atomic_write_parquet", "column_numpy", "damaged_file_error", "dual_pose8",
    "file_sha256", "fixed_list", "get_schema", "keypoints2d", "keypoints3d", "matrix4", "metric_column",
    "migrate_warehouse", "parquet_metadata", "partition_dir", "pose8", "read_parquet_file", "read_table",
    "read_table_file", "register_migration", "registry", "table", "table_files", "unsliced_table", "validate",
    "variant_parts", "vec3", "write_table", "write_table_file",
]
