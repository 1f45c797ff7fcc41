"""A sweep's results file: one row per case, written as cases finish, read back to resume.

The format is the extension's: ``.csv`` (the standard library's csv; each row appended and
flushed as its case finishes) or ``.parquet`` (pyarrow; the file rewritten atomically as cases
finish, at most every :data:`PARQUET_INTERVAL` seconds, and at the end). A file is a sweep's
when its columns are :data:`COLUMNS` (CSV: its first line; Parquet: its schema, which also
carries the key ``lie_factors.sweep``); any other existing file is refused and left as it was.
A CSV row cut short (a killed sweep) is dropped when the file is opened again.
"""

from __future__ import annotations

import csv
import math
import os
import time
from typing import Any, Iterable

from ..errors import InputError

__all__ = ["COLUMNS", "FORMATS", "ResultsFile", "read_results", "PARQUET_INTERVAL"]

#: The columns of a results file, in order, with their types.
COLUMNS: dict[str, type] = {
    "case": str, "graph": str, "kind": str, "fraction": float, "seed": int, "method": str, "run": str,
    "options": str, "status": str, "error": str,
    "planted": int, "rejected": int, "true_positives": int, "precision": float, "recall": float,
    "planted_consistent": int, "precision_consistent": float, "recall_consistent": float, "rejected_by": str,
    "ate_rmse": float, "rpe_rmse": float, "reference": str, "map_error": float,
    "final_error": float, "iterations": int, "seconds": float, "case_seconds": float, "peak_rss": int,
    "worker": str, "sweep_run": str, "robust_status": str,
}

#: The columns of the files written before ``robust_status`` (read, and resumed with the column
#: added: every earlier row gets it empty).
EARLIER_COLUMNS = tuple(name for name in COLUMNS if name != "robust_status")

#: The formats by extension.
FORMATS = (".csv", ".parquet")

#: Parquet is rewritten whole: at most this often while cases finish (seconds).
PARQUET_INTERVAL = 5.0

_MARK = b"lie_factors.sweep"

#: :func:`_read_csv`'s cut for a file of :data:`EARLIER_COLUMNS`: rewritten with every column
#: before the first new row is appended.
_EARLIER = -1


def _format(path: str) -> str:
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise InputError(f"{path}: a results file is .csv or .parquet, not {ext or 'without an extension'}")
    return ext


def _pyarrow():
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        raise InputError("a .parquet results file needs pyarrow (pip install pyarrow, or the extra: "
                         "pip install -e \".[parquet]\"); or write .csv") from None
    return pyarrow


def _typed(row: dict[str, Any]) -> dict[str, Any]:
    """``row`` with every column, each of its type (None where it has no value)."""
    out: dict[str, Any] = {}
    for name, kind in COLUMNS.items():
        value = row.get(name)
        if value is None or value == "" and kind is not str:
            out[name] = "" if kind is str else None
        elif kind is float:
            out[name] = float(value)
        elif kind is int:
            out[name] = int(value)
        else:
            out[name] = str(value)
    return out


def _read_csv(path: str) -> tuple[list[dict[str, Any]], int | None]:
    """The rows of a sweep's CSV file and the byte offset where a cut-short last row starts (None if
    the file ends with a whole row); InputError if the file is not a sweep's."""
    with open(path, "rb") as fh:
        content = fh.read()
    header = content.split(b"\n", 1)[0].rstrip(b"\r")
    columns = next((c for c in (tuple(COLUMNS), EARLIER_COLUMNS) if header == ",".join(c).encode()), None)
    if columns is None:
        raise InputError(f"{path}: not a sweep's results file (its first line is not the sweep's columns); "
                         "left as it is, choose another --out")
    cut = None
    if not content.endswith(b"\n"):
        cut = content.rfind(b"\n") + 1
        content = content[:cut]
    rows = []
    reader = csv.reader(content.decode("utf-8").splitlines()[1:])
    for values in reader:
        if len(values) != len(columns):
            raise InputError(f"{path}:{reader.line_num + 1}: a row of {len(values)} fields, the sweep's have "
                             f"{len(columns)}; left as it is")
        rows.append(_typed(dict(zip(columns, values))))
    return rows, cut if columns == tuple(COLUMNS) else _EARLIER


def _read_parquet(path: str) -> list[dict[str, Any]]:
    pa = _pyarrow()
    try:
        schema = pa.parquet.read_schema(path)
    except (pa.ArrowInvalid, OSError) as exc:
        raise InputError(f"{path}: not a sweep's results file ({exc}); left as it is, choose another --out") from None
    if list(schema.names) not in (list(COLUMNS), list(EARLIER_COLUMNS)) or _MARK not in (schema.metadata or {}):
        raise InputError(f"{path}: not a sweep's results file (its columns are not the sweep's); left as it is, "
                         "choose another --out")
    return [_typed(r) for r in pa.parquet.read_table(path).to_pylist()]


def read_results(path: str) -> list[dict[str, Any]]:
    """The rows of a sweep's results file (``.csv`` or ``.parquet``), each a dict of :data:`COLUMNS`
    (None where a case has no value, e.g. precision for a method that rejects nothing)."""
    ext = _format(path)
    if not os.path.isfile(path):
        raise InputError(f"{path}: no such results file")
    return _read_parquet(path) if ext == ".parquet" else _read_csv(path)[0]


class ResultsFile:
    """A results file open for a sweep: :attr:`rows` already there (a rerun's done cases),
    :meth:`add` a finished case's row, :meth:`close` when the sweep ends."""

    def __init__(self, path: str):
        from ..util.atomic import check_writable

        self.path, self.ext = path, _format(path)
        if self.ext == ".parquet":
            _pyarrow()
        self.rows: list[dict[str, Any]] = []
        cut = None
        if os.path.exists(path):
            if not os.path.isfile(path):
                raise InputError(f"{path}: is not a file")
            if self.ext == ".csv":
                self.rows, cut = _read_csv(path)
            else:
                self.rows = _read_parquet(path)
        check_writable(path)
        self._written = time.monotonic()
        self._pending = False
        self._cut = cut
        self._fh: Any = None
        self._cases = {r["case"] for r in self.rows}

    def _open_csv(self) -> None:
        """Open the CSV file for appending on the first new row (nothing is written before a case ends)."""
        if self._cut == _EARLIER:  # an earlier sweep's file: its rows again, with every column
            from ..util.atomic import replace_atomically

            def write(tmp):
                with open(tmp, "w", newline="", encoding="utf-8") as fh:
                    out = csv.writer(fh, lineterminator="\n")
                    out.writerow(COLUMNS)
                    out.writerows(_csv_values(r) for r in self.rows)

            replace_atomically(self.path, write, suffix=".csv")
        elif self._cut is not None:  # a row cut short by a killed sweep: its case runs again
            with open(self.path, "r+b") as fh:
                fh.truncate(self._cut)
        new = not os.path.exists(self.path)
        self._fh = open(self.path, "a", newline="", encoding="utf-8")
        self._csv = csv.writer(self._fh, lineterminator="\n")
        if new:
            self._csv.writerow(COLUMNS)

    @property
    def done(self) -> set[str]:
        """The cases that have a row."""
        return set(self._cases)

    def add(self, row: dict[str, Any]) -> bool:
        """Record a finished case's row (CSV: appended now; Parquet: the file rewritten when due);
        False, and nothing written, for a case that has a row already (Dask can hand a finished
        case back twice)."""
        if row["case"] in self._cases:
            return False
        self._cases.add(row["case"])
        row = _typed(row)
        self.rows.append(row)
        if self.ext == ".csv":
            if self._fh is None:
                self._open_csv()
            self._csv.writerow(_csv_values(row))
            self._fh.flush()
        else:
            self._pending = True
            if time.monotonic() - self._written >= PARQUET_INTERVAL:
                self._write_parquet()
        return True

    def _write_parquet(self) -> None:
        from ..util.atomic import replace_atomically

        pa = _pyarrow()
        types = {str: pa.string(), float: pa.float64(), int: pa.int64()}
        schema = pa.schema([(n, types[k]) for n, k in COLUMNS.items()], metadata={_MARK: b"1"})
        table = pa.Table.from_pylist(self.rows, schema=schema)
        replace_atomically(self.path, lambda tmp: pa.parquet.write_table(table, tmp), suffix=".parquet")
        self._written, self._pending = time.monotonic(), False

    def close(self) -> None:
        """Write what is pending and close the file."""
        if self.ext == ".csv":
            if self._fh is not None:
                self._fh.close()
        elif self._pending:
            self._write_parquet()

    def __enter__(self) -> "ResultsFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _csv_values(row: dict[str, Any]) -> list:
    """A typed row's fields as the CSV file writes them (floats by ``repr``: read back bit for bit)."""
    return ["" if v is None else (repr(v) if isinstance(v, float) and math.isfinite(v) else v) for v in row.values()]


def rows_of(rows: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows (dicts) with every column of :data:`COLUMNS`, typed."""
    return [_typed(r) for r in rows]
