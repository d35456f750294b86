"""The results table: one row per plan, sorted by id, as Parquet (pyarrow) and CSV, written atomically.

Columns: ``id``, ``task``, one column per sweep key (its key path; a sweep over the task key
``cost`` is named ``cost_type``, as in ``hoc plan --json``), then ``status``, ``converged``,
``cost``, [``T_optimal``, the duration [s] found for a free T, when a plan has one], ``iterations``, ``evaluations``,
``boundary_error``, ``limits`` (ok | violated), ``limit_violations`` (JSON text), [``collision_mode`` (enforce |
check: the mode in effect) and ``min_clearance``, the smallest signed distance [m], of a plan with a ``collision:``
section], [``best_start``,
``start_costs`` with multi-start],
``outputs`` (paths relative to the results directory), ``error``, ``solve_time_s``.

The Parquet file's metadata holds the identity of the spec the rows come from (``IDENTITY_KEY``:
``hoc_cli.batch.spec.Batch.identity``), which ``read`` checks for ``--resume``.
"""
from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any, Iterable

PARQUET, CSV = "results.parquet", "results.csv"
HEAD = ("id", "task")
TAIL = ("status", "converged", "cost", "T_optimal", "iterations", "evaluations", "boundary_error", "limits",
        "limit_violations", "collision_mode", "min_clearance", "best_start", "start_costs", "outputs", "error", "solve_time_s")
OPTIONAL = ("T_optimal", "collision_mode", "min_clearance", "best_start", "start_costs")
RENAMED = {"cost": "cost_type"}  # sweep key -> column, where the key is also a result column
TIMING = ("solve_time_s",)  # the only columns that differ between runs of the same batch
IDENTITY_KEY = b"hoc.batch.spec"  # Parquet metadata: the identity of the spec the rows come from


def column_name(sweep_key: str) -> str:
    """The results column of a sweep key."""
    return RENAMED.get(sweep_key, sweep_key)


def _types() -> dict:
    import pyarrow as pa

    return {"id": pa.string(), "task": pa.string(), "status": pa.string(), "converged": pa.bool_(),
            "cost": pa.float64(), "T_optimal": pa.float64(), "iterations": pa.int64(), "evaluations": pa.int64(),
            "boundary_error": pa.float64(), "limits": pa.string(), "limit_violations": pa.string(),
            "collision_mode": pa.string(), "min_clearance": pa.float64(),
            "best_start": pa.int64(), "start_costs": pa.list_(pa.float64()), "outputs": pa.list_(pa.string()),
            "error": pa.string(), "solve_time_s": pa.float64()}


def columns(rows: list[dict], sweep_columns: Iterable[str] = ()) -> list[str]:
    """Column order: head, sweep columns (given order, then any others found in the rows), tail."""
    fixed = set(HEAD) | set(TAIL)
    middle = list(dict.fromkeys(c for c in sweep_columns if c not in fixed))
    for row in rows:
        middle.extend(k for k in row if k not in fixed and k not in middle)
    tail = [c for c in TAIL if c not in OPTIONAL or any(row.get(c) is not None for row in rows)]
    return [*HEAD, *middle, *tail]


def table(rows: list[dict], sweep_columns: Iterable[str] = ()):
    """A ``pyarrow.Table`` of the rows sorted by id (known columns typed; a sweep column of mixed types as JSON)."""
    import pyarrow as pa

    rows = sorted(rows, key=lambda r: r["id"])
    types = _types()
    arrays, names = [], []
    for name in columns(rows, sweep_columns):
        values = [row.get(name) for row in rows]
        if name in types:
            arr = pa.array(values, type=types[name])
        else:
            try:
                arr = pa.array(values)
            except (pa.ArrowInvalid, pa.ArrowTypeError):
                arr = pa.array([None if v is None else json.dumps(v) for v in values], type=pa.string())
        arrays.append(arr)
        names.append(name)
    return pa.Table.from_arrays(arrays, names=names)


def write(out_dir: Path, tab, identity: str | None = None) -> list[Path]:
    """Write ``results.parquet`` and ``results.csv`` into ``out_dir`` (both replaced, or neither).

    ``identity`` (the spec's, ``hoc_cli.batch.spec.Batch.identity``) is stored in the Parquet file's
    metadata under ``IDENTITY_KEY``, for ``read`` to check.
    """
    import pyarrow.parquet as pq

    from hoc_cli.report.files import atomic_output, output_transaction

    if identity is not None:
        tab = tab.replace_schema_metadata({**(tab.schema.metadata or {}), IDENTITY_KEY: identity.encode("ascii")})
    paths = [out_dir / PARQUET, out_dir / CSV]
    with output_transaction():
        with atomic_output(paths[0]) as fh:
            pq.write_table(tab, fh)
        with atomic_output(paths[1]) as fh:
            fh.write(csv_text(tab).encode("utf-8"))
    return paths


def csv_text(tab) -> str:
    """The table as CSV: floats round-trip (repr), lists as JSON, missing values empty, booleans true/false."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(tab.column_names)
    for row in tab.to_pylist():
        w.writerow([_cell(v) for v in row.values()])
    return buf.getvalue()


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ""
    if isinstance(v, (list, dict)):
        return json.dumps(v, allow_nan=False, default=str) if _finite(v) else json.dumps(v, default=str)
    return str(v)


def _finite(v: Any) -> bool:
    if isinstance(v, float):
        return math.isfinite(v)
    if isinstance(v, (list, tuple)):
        return all(_finite(x) for x in v)
    return True


def read(out_dir: Path, identity: str | None = None) -> list[dict]:
    """The rows of an existing ``results.parquet`` ([] when there is none).

    With ``identity``, the file must have been written by ``hoc batch`` from a spec of that identity
    (``write``); anything else (another spec's results, a table not written by hoc batch, a file
    that is not Parquet) is an InputFileError (exit 2), so that ``--resume`` never mixes results.
    """
    import pyarrow.parquet as pq

    from hoc_cli.errors import InputFileError

    path = out_dir / PARQUET
    if not path.exists():
        return []

    def unreadable(exc: Exception) -> InputFileError:
        return InputFileError(f"cannot be read as a results table ({type(exc).__name__}); move it away or drop "
                              "--resume", file=path, key="--resume")

    if identity is not None:
        try:
            schema = pq.read_schema(path)  # the metadata first: another table is not read whole
        except Exception as exc:  # noqa: BLE001 - any unreadable file is one input error
            raise unreadable(exc) from None
        stored = (schema.metadata or {}).get(IDENTITY_KEY)
        if stored is None:
            raise InputFileError("was not written by 'hoc batch' (it records no spec); move it away or write to "
                                 "another folder (expected the results of this spec)", file=path, key="--resume")
        if stored != identity.encode("ascii"):
            raise InputFileError("holds the results of another spec (a different set of plans or outputs); rerun "
                                 "without --resume, or write to another folder (expected the results of this spec)",
                                 file=path, key="--resume")
    try:
        tab = pq.read_table(path)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is one input error
        raise unreadable(exc) from None
    rows = tab.to_pylist()
    if "id" not in tab.column_names or not all(isinstance(r.get("id"), str) for r in rows):
        raise InputFileError("has no id column of text (expected a table written by 'hoc batch')", file=path,
                             key="--resume")
    return rows
