"""Table contracts of the demoforge warehouse.

Importing this package registers every table; ``demoforge.schemas.registry()`` lists them. Each module below
declares the tables of one stage with :func:`demoforge.schemas.core.table`.
"""

from demoforge.schemas.core import (  # noqa: F401
    Column, SchemaError, TableSchema, WrittenFile, get_schema, read_table, registry, table_files, validate,
    write_table, write_table_file, read_table_file,
)
from demoforge.schemas import (
    augment, benchmarks, closed_loop, detection, ingest, ingested_demos, keypoints, llm, policy, screening, sim, synthetic,
    table3, takes, variations,
)
