"""The numba scan of a g2o file's bytes: records straight into typed arrays, no Python object per line.

Two passes over the bytes (``buf``, uint8), driven by
:func:`lie_factors.g2o.parse.scan_parse`, which owns the acceptance rules:

* :func:`count_records` — lines per tag and comment lines, to size the arrays;
* :func:`fill_records` — ids, values and line numbers of every record into
  the arrays of its tag, numbers by :func:`lie_factors.g2o.strtod.decimal`.

The tag table is arrays, one entry per record type (index ``t``): ``tags``
(T, W) uint8 padded with zeros, ``tag_len`` (T,), ``family`` (T,) codes of
the records that may share a file, ``nids`` and ``nvals`` (T,) field counts,
``fragile_tag`` (T,) the tags whose 2nd/3rd field GTSAM's 2-D second pass
reads as integers.

A line is scanned when it is blank, a comment (first token starting with
``#``) or an exact record: its tag, then ``nids`` ids (digits only, at most
:data:`~lie_factors.g2o.records.MAX_ID`) and ``nvals`` numbers, separated by
whitespace.  Anything else — an unknown tag, a second family, a field count,
an id or a number of another form — stops the scan with :data:`GIVE_UP` and
the caller parses the file the exact way.
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import kernel
from .records import MAX_ID
from .strtod import EXACT, HIGH_BITS, OK, decimal, load8

#: Scan status: all lines scanned / a line the scan does not take (see the module docstring).
DONE, GIVE_UP = 0, 1



@kernel
def _is_space(c):
    """bytes.split()'s whitespace other than the newline: space, \\t, \\v, \\f, \\r."""
    return c == 32 or c == 9 or c == 11 or c == 12 or c == 13


_NEWLINES = np.uint64(0x0A0A0A0A0A0A0A0A)
_ONES = np.uint64(0x0101010101010101)


@kernel
def _line_end(buf, i, n):
    """Index of the first newline at or after ``i`` (``n`` if none): 8 bytes a step, then 1."""
    while i + 8 <= n:
        v = load8(buf, i) ^ _NEWLINES
        if ((v - _ONES) & ~v & HIGH_BITS) != np.uint64(0):  # a zero byte: a newline among the 8
            break
        i += 8
    while i < n and buf[i] != 10:
        i += 1
    return i


@kernel
def _token_end(buf, i, n):
    while i < n and buf[i] != 10 and not _is_space(buf[i]):
        i += 1
    return i


@kernel
def _skip_space(buf, i, n):
    while i < n and _is_space(buf[i]):
        i += 1
    return i


@kernel
def _match_tag(buf, i, n, tags, tag_len, guess):
    """(t, end): the table entry of the token at ``buf[i]`` (−1 if none) and the index after it.

    ``guess`` (the previous line's entry) is tried first: records come in runs.
    """
    j = _token_end(buf, i, n)
    length = j - i
    T = len(tag_len)
    for k in range(T + 1):
        t = guess if k == 0 else k - 1
        if t < 0 or tag_len[t] != length:
            continue
        same = True
        for m in range(length):
            if buf[i + m] != tags[t, m]:
                same = False
                break
        if same:
            return t, j
    return -1, j


#: What a line is, for :func:`_line_start`.
_BLANK, _COMMENT, _RECORD = 0, 1, 2


@kernel
def _line_start(buf, i, n):
    """(kind, j, indented) of the line starting at ``buf[i]``: ``_BLANK`` (empty or whitespace
    only; j is the next line's start), ``_COMMENT`` or ``_RECORD`` (j is its first non-blank
    byte); ``indented``: it starts with whitespace.  Both passes walk lines with it."""
    if buf[i] == 10:
        return _BLANK, i + 1, False
    indented = False
    if _is_space(buf[i]):
        indented = True
        i = _skip_space(buf, i, n)
        if i == n or buf[i] == 10:
            return _BLANK, i + 1, True
    if buf[i] == 35:  # '#'
        return _COMMENT, i, indented
    return _RECORD, i, indented


@kernel
def count_records(buf, tags, tag_len, family):
    """(status, lines per tag (T,), first line of each tag (T,), comment lines, indented) of ``buf``.

    ``indented``: a line that is not empty starts with whitespace (the exact
    parse's tag order is then the order of first appearance, see
    :func:`lie_factors.g2o.parse.scan_parse`).
    """
    n = len(buf)
    counts = np.zeros(len(tag_len), dtype=np.int64)
    first = np.zeros(len(tag_len), dtype=np.int64)
    comments = 0
    indented = False
    fam = -1
    t = -1
    lineno = 0
    i = 0
    while i < n:
        lineno += 1
        kind, i, ind = _line_start(buf, i, n)
        indented = indented or ind
        if kind == _BLANK:
            continue
        if kind == _COMMENT:
            comments += 1
            i = _line_end(buf, i, n) + 1
            continue
        t, j = _match_tag(buf, i, n, tags, tag_len, t)
        if t < 0:
            return GIVE_UP, counts, first, comments, indented
        if fam < 0:
            fam = family[t]
        elif family[t] != fam:
            return GIVE_UP, counts, first, comments, indented
        if counts[t] == 0:
            first[t] = lineno
        counts[t] += 1
        i = _line_end(buf, j, n) + 1
    return DONE, counts, first, comments, indented


@kernel
def _id(buf, i, n):
    """(id, end): the all-digit token at ``buf[i]``, or (−1, end) if it is not one or exceeds MAX_ID."""
    v = 0
    j = i
    while j < n and 48 <= buf[j] <= 57:
        v = v * 10 + (buf[j] - 48)
        if v > MAX_ID:
            return -1, j
        j += 1
    if j == i or (j < n and buf[j] != 10 and not _is_space(buf[j])):
        return -1, j
    return v, j


@kernel
def _size_t_sure(buf, i, j):
    """Is the token buf[i:j] surely read by C++ ``>> size_t``: [+-]digit…, under 20 bytes (< 2^64)?"""
    k = i + 1 if buf[i] == 43 or buf[i] == 45 else i
    return k < j and 48 <= buf[k] <= 57 and j - i < 20


@kernel
def _same_bytes(buf, a, b, length):
    """Are buf[a:a+length] and buf[b:b+length] the same bytes?  8 bytes a step, then 1."""
    m = 0
    while m + 8 <= length:
        if load8(buf, a + m) != load8(buf, b + m):
            return False
        m += 8
    while m < length:
        if buf[a + m] != buf[b + m]:
            return False
        m += 1
    return True


@kernel
def fill_records(buf, tags, tag_len, nids, nvals, ninfo, fragile_tag, ids, values, lines, fragile_at,
                 comments):
    """Fill the arrays of every tag; returns (status, exact) of the file ``buf``.

    A row's information matrix (its last ``ninfo[t]`` values) written with the same bytes,
    to the end of the line, as the previous row of its tag is copied from that row rather
    than read again: most files state one matrix on every edge.

    ``ids[t]`` (n_t, nids[t]) int64, ``values[t]`` (n_t, nvals[t]) float64,
    ``lines[t]`` (n_t,) 1-based line numbers, ``fragile_at[t]`` (n_t,) int64
    (length 0 unless ``fragile_tag[t]``): where the 2nd field starts in rows
    whose 3rd field may not be read as size_t (for the exact test), else 0; ``comments`` (comment lines,) their line numbers; ``n_t`` from
    :func:`count_records`.  ``exact`` (k, 5) int64: (t, row, column, start,
    end) of each number token left to the exact conversion
    (:data:`lie_factors.g2o.strtod.EXACT`).
    """
    n = len(buf)
    row = np.zeros(len(tag_len), dtype=np.int64)
    # per tag: where the previous row's information text starts, its length to the newline
    # (-1: not reusable, e.g. a number left to the exact conversion), and that row
    info_at = np.zeros(len(tag_len), dtype=np.int64)
    info_len = np.full(len(tag_len), -1, dtype=np.int64)
    info_row = np.zeros(len(tag_len), dtype=np.int64)
    exact = np.empty((16, 5), dtype=np.int64)
    n_exact = 0
    n_comments = 0
    lineno = 0
    t = -1
    i = 0
    while i < n:
        lineno += 1
        kind, i, _ = _line_start(buf, i, n)
        if kind == _BLANK:
            continue
        if kind == _COMMENT:
            comments[n_comments] = lineno
            n_comments += 1
            i = _line_end(buf, i, n) + 1
            continue
        t, i = _match_tag(buf, i, n, tags, tag_len, t)
        r = row[t]
        row[t] = r + 1
        lines[t][r] = lineno
        out_ids = ids[t]
        out_values = values[t]
        k_ids = nids[t]
        first_info = k_ids + nvals[t] - ninfo[t] if ninfo[t] > 0 else -1
        info_start = -1
        exact_before_info = 0
        second = 0  # where the 2nd field starts
        for k in range(k_ids + nvals[t]):
            s = _skip_space(buf, i, n)
            if s >= n or buf[s] == 10:
                return GIVE_UP, exact[:n_exact]
            if k == first_info:
                L = info_len[t]
                if (L > 0 and s + L <= n and (s + L == n or buf[s + L] == 10)
                        and _same_bytes(buf, s, info_at[t], L)):
                    p = info_row[t]
                    for c in range(k - k_ids, nvals[t]):
                        out_values[r, c] = out_values[p, c]
                    i = s + L
                    break
                info_start = s
                exact_before_info = n_exact
            if k < k_ids:
                v, i = _id(buf, s, n)
                if v < 0:
                    return GIVE_UP, exact[:n_exact]
                out_ids[r, k] = v
            else:
                x, i, status = decimal(buf, s, n)
                if status == OK:
                    out_values[r, k - k_ids] = x
                elif status == EXACT:
                    if n_exact == len(exact):
                        grown = np.empty((2 * len(exact), 5), dtype=np.int64)
                        # entry by entry: a slice assignment compiles numba's shape-mismatch
                        # message, seconds of a first run
                        for q in range(n_exact):
                            for c in range(5):
                                grown[q, c] = exact[q, c]
                        exact = grown
                    exact[n_exact, 0] = t
                    exact[n_exact, 1] = r
                    exact[n_exact, 2] = k - k_ids
                    exact[n_exact, 3] = s
                    exact[n_exact, 4] = i
                    n_exact += 1
                else:
                    return GIVE_UP, exact[:n_exact]
            if k == 0:
                second = s
            # The 2nd field is an id (every record starts with one), digits C++ reads as size_t;
            # the 3rd decides.
            elif k == 1 and fragile_tag[t] and not _size_t_sure(buf, s, i):
                fragile_at[t][r] = second
        i = _skip_space(buf, i, n)
        if i < n and buf[i] != 10:
            return GIVE_UP, exact[:n_exact]
        if info_start >= 0:  # read here: the text the next rows may repeat
            info_at[t] = info_start
            info_len[t] = i - info_start if n_exact == exact_before_info else -1
            info_row[t] = r
        i += 1
    return DONE, exact[:n_exact]
