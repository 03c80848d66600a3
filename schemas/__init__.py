"""Table contracts of the demoforge warehouse.

Importing this package registers every table; ``schemas.registry()`` lists them. Each module below
declares the tables of one stage with :func:`schemas.core.table`.
"""

from schemas.core import (  # noqa: F401
    Column,
    SchemaError,
    TableSchema,
    WrittenFile,
    get_schema,
    read_table,
    registry,
    table_files,
    validate,
    write_table,
    write_table_file,
    read_table_file,
)
from schemas import (  # noqa: F401,E402  (registers tables)
    augment, benchmarks, detection, ingest, ingested_demos, keypoints, llm, policy, sim, synthetic, table3, takes, variations,
)
