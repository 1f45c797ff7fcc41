"""Parsing a g2o file's bytes into :class:`~lie_factors.g2o.records.Rows`, one per tag.

Three parses that agree on every file (``tests/g2o/test_g2o_fuzz.py`` and
``tests/g2o/test_g2o_scan.py`` check it):

* :func:`scan_parse` — the numba scan of the bytes (:mod:`.scan`): records
  straight into typed arrays, numbers correctly rounded by :mod:`.strtod`;
  it takes clean files only and gives up on anything else;
* :func:`fast_parse` — vectorized: lines grouped by tag, all numbers of a tag
  converted by numpy at once; a tag whose lines do not parse cleanly is
  re-parsed line by line;
* :func:`slow_parse` — the reference, line by line in file order, raising the
  precise error at the first malformed line.

:func:`parse` runs the scan where it pays and falls back in that order, so
every refusal is worded by the numpy or the exact parse.

A line is accepted when its tag is in :data:`~lie_factors.g2o.records.RECORDS`
and of the file's family (one dimension and pose type per file), it has the
record's field count, its ids are integers in [0, 2^56) and its values are
numbers C++ ``>>`` reads (no hex, no ``_``) and finite.  Errors name the line:
``file:line: what was expected``.

Both also list the comment lines and the "fragile" 2-D lines: those whose 2nd
or 3rd field GTSAM's ``load2D`` second pass cannot read as an integer (it
stops reading there; :func:`lie_factors.g2o.read.read_with_gtsam` hands GTSAM a
cleaned copy).
"""

from __future__ import annotations

import math
import os
import re
import sys

import numpy as np

from ..errors import InputError
from .dataset import read_bytes
from .records import MAX_ID, RECORDS, Record, Rows

_NUMBER_CHARS = b"0123456789+-.eE"
_WHITESPACE = b" \t\r\v\f\n"
_INT_RE = re.compile(rb"[+-]?[0-9]+\Z")
# What C++ `is >> double` reads as one whole token (no inf/nan/hex, no '_').
_FLOAT_RE = re.compile(rb"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z")
# GTSAM's 2-D second pass reads the 2nd and 3rd field of every line as size_t.
_SIZE_T_PREFIX = re.compile(rb"[+-]?([0-9]+)")


def _size_t_readable(tok: bytes) -> bool:
    """Does C++ `is >> size_t` succeed on this token (a digit prefix that fits 64 bits)?"""
    m = _SIZE_T_PREFIX.match(tok)
    return m is not None and int(m.group(1)) <= 2**64 - 1


def _show(token: bytes, limit: int = 40) -> str:
    text = token.decode("ascii", "backslashreplace")
    return repr(text if len(text) <= limit else text[:limit] + "...")


def _expects(rec: Record) -> str:
    return f"{rec.tag} expects {rec.nfields} fields ({rec.field_text})"


class _LineError(InputError):
    """A malformed line; ``lineno`` lets the earliest of several be reported."""

    def __init__(self, lineno: int, message: str):
        super().__init__(message)
        self.lineno = lineno


def _record_of(tag: bytes) -> Record | None:
    return RECORDS.get(tag.decode("ascii")) if tag.isascii() else None


def _parse_line(name: str, lineno: int, tokens: list[bytes], dim_of: list):
    """Check one line the slow, exact way: (record, ids, values), or raise the precise error.

    ``dim_of`` is a one-element list holding (record, line) of the first record.
    """
    where = f"{name}:{lineno}"
    tag = tokens[0]
    rec = _record_of(tag)
    if rec is None:
        known = ", ".join(RECORDS)
        raise _LineError(lineno, f"{where}: unknown tag {_show(tag)} "
                                 f"(gtsam.readG2o would skip the line; expected one of {known})")
    if dim_of[0] is None:
        dim_of[0] = (rec, lineno)
    elif rec.family != dim_of[0][0].family:
        first_rec, first = dim_of[0]
        if rec.dim != first_rec.dim:
            raise _LineError(lineno, f"{where}: {rec.tag} is a {rec.dim}-D record but line {first} made "
                                     f"this a {first_rec.dim}-D file (gtsam.readG2o reads one or the other)")
        raise _LineError(lineno, f"{where}: {rec.tag} is a {rec.group_name} record but line {first} "
                                 f"made this a {first_rec.group_name} file")
    fields = tokens[1:]
    if len(fields) != rec.nfields:
        raise _LineError(lineno, f"{where}: {_expects(rec)}, got {len(fields)}")
    nids = len(rec.ids)
    ids = []
    for k, tok in enumerate(fields[:nids]):
        if not _INT_RE.match(tok):
            raise _LineError(lineno, f"{where}: field {k + 2} ({_show(tok)}) should be an integer id")
        value = int(tok)
        if value < 0:
            raise _LineError(lineno, f"{where}: field {k + 2}: negative id {value}")
        if value > MAX_ID:
            raise _LineError(lineno, f"{where}: field {k + 2}: id {value} is larger than 2^56 - 1 "
                                     f"(GTSAM landmark keys keep 56 bits for the id)")
        ids.append(value)
    values = []
    for k, tok in enumerate(fields[nids:], start=nids):
        value = _as_float(tok)
        if value is None:
            raise _LineError(lineno, f"{where}: field {k + 2} ({_show(tok)}) is not a number")
        if not math.isfinite(value):
            raise _LineError(lineno, f"{where}: field {k + 2} ({_show(tok)}) is not finite")
        values.append(value)
    return rec, ids, values


def _as_float(tok: bytes) -> float | None:
    """The number C++ reads from the whole token, ±inf/nan for those words, else None."""
    if _FLOAT_RE.match(tok):
        return float(tok)
    if tok.isascii() and tok.lower().lstrip(b"+-") in (b"inf", b"infinity", b"nan"):
        return float(tok)
    return None


def _may_stop_gtsam(rec: Record) -> bool:
    """Is this a 2-D line whose fields GTSAM's second pass reads as ``id1 id2`` (see read_with_gtsam)?"""
    return rec.dim == 2 and not (rec.gtsam and rec.kind in ("between", "observation"))


def _is_fragile(rec: Record, tokens: list[bytes]) -> bool:
    return _may_stop_gtsam(rec) and not all(_size_t_readable(t) for t in tokens[1:3])


def _rows(rec: Record, ids: list, values: list, lines) -> Rows:
    """Rows of one tag from the per-line lists of the exact parse."""
    n = len(lines)
    return Rows(rec.tag, np.array(ids, dtype=np.int64).reshape(n, len(rec.ids)),
                np.array(values, dtype=np.float64).reshape(n, len(rec.values) + rec.info),
                np.asarray(lines, dtype=np.int64))


def slow_parse(name: str, data: bytes) -> tuple[dict[str, Rows], list[int], list[int]]:
    """Reference parse, line by line in file order: (rows, comment lines, fragile 2-D lines).

    Raises :class:`InputError` at the first malformed line.
    """
    dim_of = [None]
    acc: dict[str, tuple[Record, list, list, list]] = {}
    comments, fragile = [], []
    for lineno, line in enumerate(data.split(b"\n"), start=1):
        tokens = line.split()
        if not tokens:
            continue
        if tokens[0][:1] == b"#":
            comments.append(lineno)
            continue
        rec, ids, values = _parse_line(name, lineno, tokens, dim_of)
        if rec.tag not in acc:
            acc[rec.tag] = (rec, [], [], [])
        _, a_ids, a_values, a_lines = acc[rec.tag]
        a_ids.append(ids)
        a_values.append(values)
        a_lines.append(lineno)
        if _is_fragile(rec, tokens):
            fragile.append(lineno)
    rows = {tag: _rows(rec, i, v, ln) for tag, (rec, i, v, ln) in acc.items()}
    return rows, comments, fragile


_WS_CODES = np.frombuffer(_WHITESPACE, dtype=np.uint8)


def _tag_width() -> int:
    return max(len(t) for t in RECORDS) + 1


def _fast_groups(data: bytes):
    """Lines grouped by tag without a Python loop over lines, or None to use the slow path.

    Returns (tag → line indices (0-based, sorted), line starts, line ends,
    comment line indices).  Tags are told apart by the first W bytes of each
    line, cut at the first whitespace; a line starting with whitespace makes
    us give up (the slow path handles it).
    """
    buf = np.frombuffer(data, dtype=np.uint8)
    nl = np.flatnonzero(buf == 10)
    starts = np.concatenate(([0], nl + 1))
    ends = np.concatenate((nl, [len(buf)]))
    used = np.flatnonzero(ends > starts)
    if used.size == 0:
        return {}, starts, ends, np.zeros(0, dtype=np.int64)
    W = _tag_width()
    padded = np.concatenate((buf, np.zeros(W, dtype=np.uint8)))
    idx = starts[used, None] + np.arange(W)
    win = padded[idx]
    if np.isin(win[:, 0], _WS_CODES).any():
        return None
    win[idx >= ends[used, None]] = 32
    cut = np.cumsum(np.isin(win, _WS_CODES), axis=1) > 0
    win[cut] = 0
    codes, inverse = np.unique(np.ascontiguousarray(win).view(f"S{W}").ravel(), return_inverse=True)
    inverse = inverse.ravel()
    order = np.argsort(inverse, kind="stable")
    bounds = np.concatenate(([0], np.cumsum(np.bincount(inverse, minlength=len(codes)))))
    groups, comments = {}, []
    for c, code in enumerate(codes.tolist()):
        lines = used[order[bounds[c]:bounds[c + 1]]]
        if code[:1] == b"#":
            comments.append(lines)
        else:
            groups[code] = lines
    comments = np.sort(np.concatenate(comments)) if comments else np.zeros(0, dtype=np.int64)
    return groups, starts, ends, comments


def _parse_group(rec: Record, data: bytes, lines: np.ndarray, starts, ends) -> Rows | None:
    """All lines of one tag (0-based indices) → Rows, or None if anything looks off."""
    n = len(lines)
    breaks = np.flatnonzero(np.diff(lines) != 1)
    run_first = np.concatenate(([0], breaks + 1))
    run_last = np.concatenate((breaks, [n - 1]))
    blob = b"\n".join([data[starts[lines[f]]:ends[lines[l]]]
                       for f, l in zip(run_first.tolist(), run_last.tolist())])
    nf = rec.nfields + 1
    tokens = blob.split()
    if len(tokens) != n * nf:
        return None
    table = np.array(tokens, dtype="S").reshape(n, nf)[:, 1:]
    if np.ascontiguousarray(table).tobytes().translate(None, _NUMBER_CHARS + b"\0"):
        return None
    nids = len(rec.ids)
    if not np.char.isdigit(table[:, :nids]).all():
        return None  # '+5', '1.0', '-3', ... : the slow path says which are ids
    try:
        # Restricted to [0-9+-.eE], float conversion of whole tokens accepts what
        # C++ `>>` reads as one number (forms like '1e' or '1.2.3' fail here).
        values = table[:, nids:].astype(np.float64)
        ids_f = table[:, :nids].astype(np.float64)
    except ValueError:
        return None
    # Ids are compared with MAX_ID as integers: as floats, 2^56 − 1 and the next few
    # integers all round to 2^56.  From 2^57 on, a float says "too large" surely.
    if not np.isfinite(values).all() or (ids_f >= 2.0**57).any():
        return None
    if (ids_f >= 2.0**53).any():  # beyond exact floats: integers from the text
        ids = np.array([[int(t) for t in row] for row in table[:, :nids].tolist()], dtype=np.int64)
        if (ids > MAX_ID).any():
            return None
    else:
        ids = ids_f.astype(np.int64)
    rows = Rows(rec.tag, ids.reshape(n, nids), np.ascontiguousarray(values), lines + 1)
    if _may_stop_gtsam(rec):
        rows.fragile = _fragile_rows(table[:, :2])
    return rows


def _fragile_rows(first_two: np.ndarray) -> np.ndarray:
    """Rows whose 2nd or 3rd field C++ cannot read as size_t (0-based row indices)."""
    bad = np.zeros(len(first_two), dtype=bool)
    for col in np.ascontiguousarray(first_two).T:
        col = np.ascontiguousarray(col)
        b = np.frombuffer(col.tobytes(), dtype=np.uint8).reshape(len(col), -1)
        c0 = b[:, 0]
        c1 = b[:, 1] if b.shape[1] > 1 else np.zeros_like(c0)
        digit0 = (c0 >= 48) & (c0 <= 57)
        digit1 = (c1 >= 48) & (c1 <= 57)
        sign = (c0 == 43) | (c0 == 45)
        # 20+ characters may hold a digit run that overflows 64 bits: the exact test decides.
        long = np.char.str_len(col) >= 20
        bad |= ~(digit0 | (sign & digit1)) | long
    rows = np.flatnonzero(bad)
    exact = [r for r in rows.tolist() if not all(_size_t_readable(t) for t in first_two[r].tolist())]
    return np.asarray(exact, dtype=np.int64)


def _slow_group(name: str, rec: Record, data: bytes, lines, starts, ends) -> Rows:
    """Line-by-line parse of one tag's lines (0-based indices); raises at its first bad line."""
    dim_of = [(rec, int(lines[0]) + 1)]
    ids, values, fragile = [], [], []
    for row, i in enumerate(lines.tolist()):
        tokens = data[starts[i]:ends[i]].split()
        _, row_ids, row_values = _parse_line(name, i + 1, tokens, dim_of)
        ids.append(row_ids)
        values.append(row_values)
        if _is_fragile(rec, tokens):
            fragile.append(row)
    rows = _rows(rec, ids, values, lines + 1)
    if _may_stop_gtsam(rec):
        rows.fragile = np.asarray(fragile, dtype=np.int64)
    return rows


def fast_parse(name: str, data: bytes):
    """Vectorized parse: (rows, comment lines, fragile lines), or None if the slow path must run.

    A tag group that does not parse cleanly is re-parsed line by line (exact);
    unknown tags and a second dimension are located from the groups.  The
    earliest problem line of all is the one reported (:class:`InputError`).
    """
    grouped = _fast_groups(data)
    if grouped is None:
        return None
    groups, starts, ends, comments = grouped
    if not groups:
        return {}, (comments + 1).tolist(), []
    first_line = {tag: int(lines[0]) for tag, lines in groups.items()}
    first_tag = min(first_line, key=first_line.get)
    first_rec = _record_of(first_tag)
    problems: list[tuple[int, str]] = []
    rows: dict[str, Rows] = {}
    alien = []  # first lines of unknown tags and of the other dimension's records
    for tag_b, lines in groups.items():
        rec = _record_of(tag_b)
        if rec is None or (first_rec is not None and rec.family != first_rec.family):
            alien.append(int(lines[0]))
            continue
        parsed = _parse_group(rec, data, lines, starts, ends)
        if parsed is None:
            try:
                parsed = _slow_group(name, rec, data, lines, starts, ends)
            except _LineError as exc:
                problems.append((exc.lineno, str(exc)))
                continue
        rows[rec.tag] = parsed
    if alien:  # only the earliest matters (a CSV file has thousands of "tags")
        i = min(alien)
        first = (first_rec, first_line[first_tag] + 1) if first_rec is not None else None
        try:
            _parse_line(name, i + 1, data[starts[i]:ends[i]].split(), [first])
        except _LineError as exc:
            problems.append((exc.lineno, str(exc)))
    if problems:
        raise InputError(min(problems)[1])
    fragile = []
    for r in rows.values():
        if r.fragile is not None and len(r.fragile):
            fragile.extend(r.lines[r.fragile].tolist())
    return rows, (comments + 1).tolist(), sorted(fragile)


def _scan_table():
    """The record table as the arrays :mod:`.scan` takes (one entry per record type, RECORDS order).

    Returns (records, tags (T, W) uint8, tag_len, family, nids, nvals, ninfo, fragile_tag).
    """
    recs = list(RECORDS.values())
    tags = np.zeros((len(recs), max(len(r.tag) for r in recs)), dtype=np.uint8)
    for t, r in enumerate(recs):
        tags[t, :len(r.tag)] = np.frombuffer(r.tag.encode("ascii"), dtype=np.uint8)
    families: dict = {}
    family = np.array([families.setdefault(r.family, len(families)) for r in recs], dtype=np.int64)
    return (recs, tags, np.array([len(r.tag) for r in recs], dtype=np.int64), family,
            np.array([len(r.ids) for r in recs], dtype=np.int64),
            np.array([len(r.values) + r.info for r in recs], dtype=np.int64),
            np.array([r.info for r in recs], dtype=np.int64),
            np.array([_may_stop_gtsam(r) for r in recs]))


def scan_parse(data: bytes):
    """The numba scan of the bytes (:mod:`.scan`): (rows, comment lines, fragile lines), or None.

    None when a line is not a comment or an exact record of the file's family
    (the other parses find and word the problem), or a number is not finite.
    Otherwise the result of :func:`fast_parse` (or of :func:`slow_parse` for a
    file with indented lines, where fast_parse gives up), tags in the same order.
    """
    from .scan import DONE, count_records, fill_records  # numba: only where it pays (:func:`parse`)

    recs, tags, tag_len, family, nids, nvals, ninfo, fragile_tag = _scan_table()
    buf = np.frombuffer(data, dtype=np.uint8)
    status, counts, first, n_comments, indented = count_records(buf, tags, tag_len, family)
    if status != DONE:
        return None
    ids = tuple(np.empty((n, k), dtype=np.int64) for n, k in zip(counts, nids))
    values = tuple(np.empty((n, m), dtype=np.float64) for n, m in zip(counts, nvals))
    lines = tuple(np.empty(n, dtype=np.int64) for n in counts)
    fragile_at = tuple(np.zeros(n if f else 0, dtype=np.int64) for n, f in zip(counts, fragile_tag))
    comments = np.empty(n_comments, dtype=np.int64)
    status, exact = fill_records(buf, tags, tag_len, nids, nvals, ninfo, fragile_tag, ids, values,
                                 lines, fragile_at, comments)
    if status != DONE:
        return None
    for t, r, col, start, end in exact.tolist():  # the scan's grammar is _FLOAT_RE's: float() reads it
        value = float(data[start:end])
        if not math.isfinite(value):
            return None
        values[t][r, col] = value
    rows: dict[str, Rows] = {}
    fragile = []
    # fast_parse lists tags sorted; slow_parse, which parses files with indented lines, as they appear
    order = (lambda t: first[t]) if indented else (lambda t: recs[t].tag)
    for t in sorted(np.flatnonzero(counts).tolist(), key=order):
        rec = recs[t]
        rows[rec.tag] = Rows(rec.tag, ids[t], values[t], lines[t])
        if fragile_tag[t]:
            maybe = np.flatnonzero(fragile_at[t])
            bad = [k for k, at in zip(maybe.tolist(), fragile_at[t][maybe].tolist())
                   if not all(_size_t_readable(tok) for tok in _line_from(data, at).split()[:2])]
            if not indented:  # as fast_parse records them (slow_parse only lists the lines)
                rows[rec.tag].fragile = np.asarray(bad, dtype=np.int64)
            fragile.extend(lines[t][bad].tolist())
    return rows, comments.tolist(), sorted(fragile)


def _line_from(data: bytes, start: int) -> bytes:
    end = data.find(b"\n", start)
    return data[start:end if end >= 0 else len(data)]


#: From this size on the numba scan parses a file even when numba is not loaded yet: the
#: size at which importing numba and loading the scan's cached code costs what the numpy
#: parse spends (the scan itself reads several times faster; docs/benchmarks.md).
SCAN_MIN_BYTES = 8 << 20


def parse(name: str, data) -> tuple[dict[str, Rows], list[int], list[int]]:
    """(rows by tag, comment lines, fragile 2-D lines) of ``data``; ``name`` heads the error messages.

    ``data``: the file's bytes.
    The numba scan when it pays (numba already loaded, or at least
    :data:`SCAN_MIN_BYTES`: smaller files are checked without importing
    numba); else, or where it gives up, the vectorized parse, or the exact one
    where that gives up (a line starting with whitespace).  All three give the
    same rows.  Raises :class:`InputError` naming the first bad line.
    """
    parsed = None
    # (the scan reads digits from little-endian words, see .strtod)
    if (len(data) >= SCAN_MIN_BYTES or "numba" in sys.modules) and sys.byteorder == "little":
        parsed = scan_parse(data)
    if parsed is None:
        parsed = fast_parse(name, data)
        if parsed is None:
            parsed = slow_parse(name, data)
    return parsed


def parse_file(path: str) -> tuple[dict[str, Rows], list[int], list[int]]:
    """:func:`parse` of the file at ``path``, read whole into memory once.

    (Not memory-mapped: a file truncated by another process while mapped would
    kill this one with SIGBUS; a read costs the same resident memory.)
    """
    return parse(os.path.basename(path), read_bytes(path))
