"""Data checked against a contract: every column cast to its declared type, or a SchemaError naming it."""

from __future__ import annotations

from typing import Any, Mapping

import pyarrow as pa

from demoforge.schemas.contracts import Column, SchemaError, TableSchema, get_schema


def _fixed_shape(t: pa.DataType) -> list[int]:
    shape = []
    while pa.types.is_fixed_size_list(t):
        shape.append(t.list_size)
        t = t.value_type
    return shape


def _coerce_column(schema: TableSchema, col: Column, values: pa.ChunkedArray | pa.Array) -> pa.Array:
    """Cast one column to its contract type, or raise SchemaError naming it."""
    where = f"table {schema.name!r}, column {col.name!r}"
    actual = values.type
    if actual == col.type:
        out = values
    else:
        expected_shape = _fixed_shape(col.type)
        if expected_shape:
            # Accept variable-size lists (e.g. from pandas/numpy) only if every row has the exact shape.
            depth = 0
            t = actual
            while pa.types.is_list(t) or pa.types.is_large_list(t) or pa.types.is_fixed_size_list(t):
                depth += 1
                t = t.value_type
            if depth != len(expected_shape):
                raise SchemaError(
                    f"{where}: expected {col.type} (shape {expected_shape}), got {actual}"
                )
            try:
                out = values.cast(col.type)
            except pa.ArrowException as e:
                raise SchemaError(
                    f"{where}: expected fixed shape {expected_shape} of {col.type}; {e}"
                ) from None
        else:
            if not _castable_scalar(actual, col.type):
                raise SchemaError(f"{where}: expected {col.type}, got {actual}")
            try:
                out = values.cast(col.type, safe=True)
            except pa.ArrowException as e:
                raise SchemaError(f"{where}: cannot store {actual} as {col.type}: {e}") from None
    if not col.nullable and out.null_count:
        raise SchemaError(f"{where}: {out.null_count} null value(s) in a non-nullable column")
    if not col.nullable and _fixed_shape(col.type):
        # Nulls nested inside fixed-size lists (e.g. a missing coordinate) are refused too.
        flat = out
        if isinstance(flat, pa.ChunkedArray):
            flat = flat.combine_chunks()
        while pa.types.is_fixed_size_list(flat.type):
            flat = flat.flatten()
        if flat.null_count:
            raise SchemaError(f"{where}: {flat.null_count} null element(s) inside its fixed-size lists")
    return out


def _castable_scalar(actual: pa.DataType, expected: pa.DataType) -> bool:
    """Only lossless-in-kind casts: ints widen to ints/floats, floats to floats, strings to strings."""
    if pa.types.is_null(actual):
        return True
    groups = [
        (pa.types.is_integer, (pa.types.is_integer, pa.types.is_floating)),
        (pa.types.is_floating, (pa.types.is_floating,)),
        (lambda t: pa.types.is_string(t) or pa.types.is_large_string(t),
         (pa.types.is_string, pa.types.is_large_string, pa.types.is_dictionary)),
        (pa.types.is_boolean, (pa.types.is_boolean,)),
        (pa.types.is_timestamp, (pa.types.is_timestamp,)),
        (pa.types.is_dictionary, (pa.types.is_string, pa.types.is_dictionary)),
    ]
    for is_src, targets in groups:
        if is_src(actual):
            return any(f(expected) for f in targets)
    return False


def validate(schema: TableSchema | str, data: pa.Table | Any) -> pa.Table:
    """Return ``data`` as a pyarrow Table exactly in the contract's schema, or raise SchemaError."""
    if isinstance(schema, str):
        schema = get_schema(schema)
    tbl = _as_arrow(data)
    present = set(tbl.column_names)
    expected = [c.name for c in schema.columns]
    missing = [n for n in expected if n not in present]
    extra = [n for n in tbl.column_names if n not in expected]
    if missing:
        raise SchemaError(f"table {schema.name!r}: missing column(s) {missing}")
    if extra:
        raise SchemaError(f"table {schema.name!r}: unexpected column(s) {extra}")
    arrays = [_coerce_column(schema, c, tbl.column(c.name)) for c in schema.columns]
    return pa.Table.from_arrays(arrays, schema=schema.arrow)


def _as_arrow(data: Any) -> pa.Table:
    if isinstance(data, pa.Table):
        return data
    if isinstance(data, Mapping):
        return pa.table({k: _to_arrow_values(v) for k, v in data.items()})
    try:
        import pandas as pd
    except ImportError:  # pragma: no cover - pandas is a dependency
        pd = None
    if pd is not None and isinstance(data, pd.DataFrame):
        return pa.table({k: _to_arrow_values(data[k].to_list()) for k in data.columns})
    raise TypeError(f"cannot write {type(data).__name__}; pass a pyarrow Table, DataFrame or dict of columns")


def _to_arrow_values(v: Any) -> pa.Array:
    import numpy as np

    if isinstance(v, (pa.Array, pa.ChunkedArray)):
        return v
    if isinstance(v, np.ndarray) and v.ndim > 1:
        # (rows, *shape) -> nested fixed-size lists without a Python loop.
        arr = pa.array(np.ascontiguousarray(v).reshape(-1))
        for size in reversed(v.shape[1:]):
            arr = pa.FixedSizeListArray.from_arrays(arr, size)
        return arr
    return pa.array(v)


def column_numpy(table: pa.Table, name: str):
    """A column as a numpy array; nested fixed-size lists become trailing dimensions (rows, *shape)."""
    import numpy as np

    col = table.column(name).combine_chunks()
    shape: list[int] = []
    t = col.type
    while pa.types.is_fixed_size_list(t):
        shape.append(t.list_size)
        t = t.value_type
    flat = col
    for _ in shape:
        flat = flat.flatten()
    return np.asarray(flat.to_numpy(zero_copy_only=False)).reshape((len(col),) + tuple(shape))
