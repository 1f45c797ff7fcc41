"""Decimal text → double in numba, correctly rounded: Python's ``float`` of the same token, bit for bit.

:func:`decimal` reads one token of a byte buffer with the grammar of a number
C++ ``is >> double`` reads whole (the :mod:`lie_factors.g2o.parse` rule):
``[+-]? (digits [. digits?] | . digits) ([eE] [+-]? digits)?``, no inf/nan,
no hex.  The token is w · 10^q with w the (at most 19) significant digits;
the value is correctly rounded (to nearest, ties to even) by one of two exact
methods:

* Clinger's fast path: w ≤ 2^53 and |q| ≤ 22.  Then w and 10^|q| are doubles
  exactly (5^22 < 2^53), so one IEEE multiply or divide rounds the exact
  value once: the correctly rounded result.
* Eisel–Lemire (Lemire, "Number parsing at a gigabyte per second", 2021, as
  in the fast_float library): −342 ≤ q ≤ 308.  w, shifted to 64 significant
  bits, times the 128-bit truncation of 5^q (:data:`POW5`) gives the top bits
  of w · 10^q; for a normal result (no subnormal, no overflow) the
  truncations of the table and of the product cannot move the rounding,
  except perhaps when the product's low word is all ones outside −27 ≤ q ≤ 55:
  those go to the exact conversion.

Everything else (more than 19 significant digits, an exponent out of the
table, a subnormal or overflowing result, the undecidable products) is
:data:`EXACT`: valid, and left to Python's ``float`` (exact, slow).  Zero is
±0.0 whatever the exponent.  ``tests/g2o/test_g2o_strtod.py`` compares every
route with ``float`` on adversarial and random tokens.

Digits are read eight at a time from 64-bit words (fast_float's SWAR
formulas), which assumes a little-endian machine (x86-64, arm64).
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from ..kernels.jit import kernel

#: :func:`decimal` status: the value is the correctly rounded double.
OK = 0
#: Valid number, not converted here: the caller converts the token with Python's ``float``.
EXACT = 1
#: Not a number C++ ``>>`` reads as one whole token.
SYNTAX = 2

#: q range of the Eisel–Lemire table (fast_float's): 10^−343 rounds to 0, 10^309 overflows.
Q_MIN, Q_MAX = -342, 308


def _pow5_128() -> np.ndarray:
    """128-bit truncations of 5^q, q in [Q_MIN, Q_MAX], top bit set: shape (Q_MAX − Q_MIN + 1, 2), (high, low).

    fast_float's table: for q ≥ 0, 5^q shifted (exact for q ≤ 55); for q < 0,
    ⌊2^b / 5^−q⌋ + 1 cut to 128 bits (the reciprocal rounded up for q ≥ −27).
    """
    words = []
    for q in range(Q_MIN, Q_MAX + 1):
        if q < 0:
            p = 5 ** -q
            z = p.bit_length() if p & (p - 1) else p.bit_length() - 1  # smallest z with 2^z ≥ 5^−q
            c = 2 ** (z + 127 if q >= -27 else 2 * z + 128) // p + 1
        else:
            c = 5 ** q
            if c < 2 ** 127:
                c <<= 127 - (c.bit_length() - 1)
        c >>= max(0, c.bit_length() - 128)
        words.append((c >> 64, c & (2 ** 64 - 1)))
    return np.array(words, dtype=np.uint64)


POW5 = _pow5_128()
#: 10^k, k = 0 … 22: exact doubles (5^22 < 2^53).
_P10 = np.array([10.0 ** k for k in range(23)])
#: 2^(e − 1075) for a biased exponent e = 1 … 2046: a 53-bit mantissa m times it is the double m·2^(e−1075), exactly.
_POW2 = np.array([math.ldexp(1.0, e - 1075) for e in range(2047)])

_U0, _U1, _U2, _U3 = np.uint64(0), np.uint64(1), np.uint64(2), np.uint64(3)
_U10, _U32, _U63 = np.uint64(10), np.uint64(32), np.uint64(63)
_ALL_ONES = np.uint64(0xFFFFFFFFFFFFFFFF)
_TWO53 = np.uint64(2 ** 53)
_MAX_W = np.uint64(10 ** 18)  # w < this takes one more digit and stays < 10^19 < 2^64
_MAX_W8 = np.uint64(10 ** 11)  # w < this takes eight more
_U10_8 = np.uint64(10 ** 8)
# SWAR digit tests and conversion of 8 bytes at once (fast_float's, for little-endian words)
_ZEROS = np.uint64(0x3030303030303030)
_ADD46 = np.uint64(0x4646464646464646)
HIGH_BITS = np.uint64(0x8080808080808080)
_MASK_8 = np.uint64(0x000000FF000000FF)
_MUL1 = np.uint64(0x000F424000000064)  # 100 + (1000000 << 32)
_MUL2 = np.uint64(0x0000271000000001)  # 1 + (10000 << 32)
_PREC_MASK = np.uint64(0xFFFFFFFFFFFFFFFF >> 55)  # the low 64 − (52 + 3) bits of the high word


# Numba intrinsics for what numba does not spell: the 128-bit product of two uint64
# (one x86-64 ``mul``, against four 32-bit products and their carries), count leading
# zeros, and an unaligned 8-byte load.

@intrinsic
def _mul128(typingctx, a, b):
    """(high, low) 64-bit words of the exact product of two uint64."""
    def codegen(context, builder, sig, args):
        wide = ir.IntType(128)
        p = builder.mul(builder.zext(args[0], wide), builder.zext(args[1], wide))
        high = builder.trunc(builder.lshr(p, ir.Constant(wide, 64)), ir.IntType(64))
        return context.make_tuple(builder, sig.return_type, (high, builder.trunc(p, ir.IntType(64))))

    return types.UniTuple(types.uint64, 2)(types.uint64, types.uint64), codegen


@intrinsic
def _leading_zeros(typingctx, w):
    """Leading zero bits of a uint64 w > 0."""
    def codegen(context, builder, sig, args):
        lz = builder.ctlz(args[0], ir.Constant(ir.IntType(1), 1))
        return builder.zext(lz, ir.IntType(64)) if lz.type.width < 64 else lz

    return types.int64(types.uint64), codegen


@kernel
def eisel_lemire(w, q):
    """The correctly rounded double of w · 10^q (w uint64 > 0), and whether it was decided here.

    fast_float's ``compute_float`` for binary64, restricted to normal
    results; (0.0, False) where it would need the subnormal branch, overflow
    or the product's low word is all ones outside −27 ≤ q ≤ 55 (where the
    table is exact).
    """
    if q < Q_MIN or q > Q_MAX:
        return 0.0, False
    lz = _leading_zeros(w)
    w = w << np.uint64(lz)
    index = q - Q_MIN
    high, low = _mul128(w, POW5[index, 0])
    if (high & _PREC_MASK) == _PREC_MASK:  # the bits below the rounding bit may carry: add the next word
        high2, _ = _mul128(w, POW5[index, 1])
        low = low + high2
        if high2 > low:
            high += _U1
    if low == _ALL_ONES and (q < -27 or q > 55):
        return 0.0, False
    upper = high >> _U63
    shift = upper + np.uint64(64 - 52 - 3)
    mantissa = high >> shift
    # binary exponent: floor(q·log2(10)) + 63 + upper − lz, biased by 1023
    power2 = ((217706 * q) >> 16) + 63 + np.int64(upper) - lz + 1023
    if power2 <= 0:
        return 0.0, False
    # a tie (the dropped bits exactly half an ulp) rounds to even: possible only where 5^q is exact
    if low <= _U1 and -4 <= q <= 23 and (mantissa & _U3) == _U1 and (mantissa << shift) == high:
        mantissa &= ~_U1
    mantissa += mantissa & _U1
    mantissa >>= _U1
    if mantissa >= (_U2 << np.uint64(52)):
        mantissa = _U1 << np.uint64(52)
        power2 += 1
    if power2 >= 2047:
        return 0.0, False
    return float(mantissa) * _POW2[power2], True


@intrinsic
def load8(typingctx, buf, i):
    """The 8 bytes buf[i:i+8] of a uint8 array as one little-endian uint64 (i + 8 ≤ len(buf)).

    One unaligned load (numba would load and shift the 8 bytes one by one).
    """
    def codegen(context, builder, sig, args):
        data = context.make_array(sig.args[0])(context, builder, args[0]).data
        word = builder.bitcast(builder.gep(data, [args[1]]), ir.IntType(64).as_pointer())
        return builder.load(word, align=1)

    return types.uint64(buf, types.intp), codegen


@kernel
def _eight_digits(v):
    """Are all 8 bytes of ``v`` (from :func:`load8`) ASCII digits?"""
    return (((v + _ADD46) | (v - _ZEROS)) & HIGH_BITS) == _U0


@kernel
def _eight_digits_value(v):
    """The number written by the 8 ASCII digits of ``v`` (first digit in the low byte)."""
    v = v - _ZEROS
    v = v * _U10 + (v >> np.uint64(8))
    return (((v & _MASK_8) * _MUL1) + (((v >> np.uint64(16)) & _MASK_8) * _MUL2)) >> _U32


@kernel
def decimal(buf, i, n):
    """Read the number token starting at ``buf[i]`` (uint8 array, ``n`` its used length).

    Returns (value, end, status): ``end`` the index after the token (the token
    ends at whitespace, a newline or ``n``), ``status`` :data:`OK` (value
    exact), :data:`EXACT` (valid, value not computed) or :data:`SYNTAX`.
    """
    neg = False
    c = buf[i] if i < n else 0
    if c == 43 or c == 45:  # + -
        neg = c == 45
        i += 1
    w = _U0  # the significant digits read (leading zeros add nothing)
    q = 0
    many = False  # more than 19 significant digits: not in w
    seen = False
    while i < n and 48 <= buf[i] <= 57:
        seen = True
        if w < _MAX_W:
            w = w * _U10 + np.uint64(buf[i] - 48)
        else:
            many = True
        i += 1
    if i < n and buf[i] == 46:  # .
        i += 1
        # 8 digits at a time while w keeps room for them (w < 10^11: w·10^8 + 8 digits < 10^19)
        while i + 8 <= n and w < _MAX_W8:
            v = load8(buf, i)
            if not _eight_digits(v):
                break
            w = w * _U10_8 + _eight_digits_value(v)
            q -= 8
            i += 8
            seen = True
        while i < n and 48 <= buf[i] <= 57:
            seen = True
            if w < _MAX_W:
                w = w * _U10 + np.uint64(buf[i] - 48)
                q -= 1
            else:
                many = True
            i += 1
    if not seen:
        return 0.0, i, SYNTAX
    if i < n and (buf[i] == 101 or buf[i] == 69):  # e E
        i += 1
        eneg = False
        if i < n and (buf[i] == 43 or buf[i] == 45):
            eneg = buf[i] == 45
            i += 1
        if not (i < n and 48 <= buf[i] <= 57):
            return 0.0, i, SYNTAX
        e = 0
        while i < n and 48 <= buf[i] <= 57:
            if e < 100_000_000:  # beyond any double's reach either way; no overflow
                e = e * 10 + (buf[i] - 48)
            i += 1
        q += -e if eneg else e
    if i < n and not (buf[i] == 32 or 9 <= buf[i] <= 13):
        return 0.0, i, SYNTAX
    if many:
        return 0.0, i, EXACT
    if w == _U0:
        return -0.0 if neg else 0.0, i, OK
    if w <= _TWO53 and -22 <= q <= 22:
        v = float(w)
        v = v * _P10[q] if q >= 0 else v / _P10[-q]
        return -v if neg else v, i, OK
    x, done = eisel_lemire(w, q)
    if not done:
        return 0.0, i, EXACT
    return -x if neg else x, i, OK
