"""lie_factors.g2o.strtod: the double of every number token is Python's ``float`` of it, bit for bit.

Each route is compared with ``float`` (correctly rounded): Clinger's fast path, Eisel–Lemire, and
the tokens left to the exact conversion (:data:`~lie_factors.g2o.strtod.EXACT`); the grammar is
the parse's ``_FLOAT_RE`` (what C++ ``>>`` reads as one whole number).
"""

from __future__ import annotations

import random
import struct
from fractions import Fraction

import numpy as np
import pytest
from numba import njit

from lie_factors.g2o import strtod
from lie_factors.g2o.parse import _FLOAT_RE


@njit
def _decimal_all(buf, starts):
    values = np.empty(len(starts))
    ends = np.empty(len(starts), dtype=np.int64)
    status = np.empty(len(starts), dtype=np.int64)
    for k in range(len(starts)):
        values[k], ends[k], status[k] = strtod.decimal(buf, starts[k], len(buf))
    return values, ends, status


@njit
def _eisel_lemire_all(w, q):
    values = np.empty(len(w))
    done = np.empty(len(w), dtype=np.bool_)
    for k in range(len(w)):
        values[k], done[k] = strtod.eisel_lemire(w[k], q[k])
    return values, done


def _bits(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64).view(np.uint64)


def _decimal(tokens: list[bytes]):
    """(values, status) of every token, read from one buffer where they stand separated by spaces."""
    blob = b" ".join(tokens)
    starts = np.cumsum([0] + [len(t) + 1 for t in tokens[:-1]]).astype(np.int64)
    values, ends, status = _decimal_all(np.frombuffer(blob, dtype=np.uint8), starts)
    valid = status != strtod.SYNTAX
    assert np.array_equal(ends[valid], starts[valid] + [len(t) for t, v in zip(tokens, valid) if v])
    return values, status


def _assert_as_float(tokens: list[bytes]) -> np.ndarray:
    """Every OK value is float(token) bit for bit; EXACT and SYNTAX exactly where the grammar says."""
    values, status = _decimal(tokens)
    grammar = np.array([_FLOAT_RE.match(t) is not None for t in tokens])
    assert np.array_equal(status == strtod.SYNTAX, ~grammar), [t for t, s, g in zip(tokens, status, grammar)
                                                             if (s == strtod.SYNTAX) == g][:5]
    ok = status == strtod.OK
    expected = np.array([float(t) if g else 0.0 for t, g in zip(tokens, grammar)])
    wrong = np.flatnonzero(ok & (_bits(values) != _bits(expected)))
    assert wrong.size == 0, [(tokens[k], values[k], expected[k]) for k in wrong[:5]]
    return status


ADVERSARIAL = [
    # zeros and signs, whatever the exponent
    "0", "-0", "+0", "0.0", "-0.0", "00000.00000", "0e999999999999", "-0e-999999999999", ".0", "0.",
    # forms C++ reads: leading +, no integer part, no fraction, exponents
    ".5", "5.", "+.5", "-5.", "+5", "1e5", "1E5", "1e+5", "1e-5", "+1.5e-3", "-.25E+2", "5.e3",
    "007", "0.000123", "123000e-3",
    # Clinger's edges: w ≤ 2^53, |q| ≤ 22
    "9007199254740992", "9007199254740992e22", "9007199254740992e-22", "1e22", "1e-22", "1e23",
    "1e-23", "4503599627370497.5",
    # ties between doubles: round half to even (Eisel–Lemire's exact range of q)
    "9007199254740993", "9007199254740995", "9007199254740993e0", "900719925474099.3e1",
    "18014398509481986", "18014398509481990", "9007199254740993000e-3",
    # 17 and 19 significant digits (Eisel–Lemire)
    "1.0055197110184377", "0.0006277476135816208", "3.0000000000000004", "1.0000000000000002",
    "0.30000000000000004", "1234567890123456789", "9999999999999999999", "1.7976931348623157e308",
    "2.2250738585072014e-308", "4.9406564584124654e-300",
    # more than 19 significant digits, subnormals, overflow: the exact conversion
    "12345678901234567890", "18446744073709551616", "0.1000000000000000055511151231257827",
    "1.7976931348623158e308", "1.7976931348623159e308", "1e308", "1e309", "-1e400", "1e-400",
    "2.2250738585072011e-308", "2.2250738585072012e-308", "4.9406564584124654e-324", "5e-324",
    "2.4703282292062327e-324", "2.4703282292062328e-324", "1e-320", "123456789e-350",
    "9007199254740991.4999999999999999999", "1" + "0" * 400, "0." + "0" * 400 + "1",
    # not numbers C++ reads whole
    ".", "+", "-", "e5", ".e5", "1e", "1e+", "1e-", "1.2.3", "1..2", "--1", "+-1", "1_0", "0x10",
    "inf", "-inf", "nan", "infinity", "1e5.5", "1,5", "1e5e5", "1-2", "1+", "١", "é", "\x00", "5f",
]


def test_adversarial_tokens():
    tokens = [t.encode("utf-8") for t in ADVERSARIAL]
    status = _assert_as_float(tokens)
    by = dict(zip(ADVERSARIAL, status.tolist()))
    # the routes are the documented ones
    for t in ("0", ".5", "1e22", "9007199254740993", "1.0055197110184377", "1234567890123456789",
              "1.7976931348623157e308", "2.2250738585072014e-308", "1e23"):
        assert by[t] == strtod.OK, t
    for t in ("12345678901234567890", "1e309", "1e-400", "5e-324", "2.2250738585072011e-308",
              "1.7976931348623159e308"):
        assert by[t] == strtod.EXACT, t


def _random_tokens(rng: random.Random, n: int) -> list[bytes]:
    out = []
    for _ in range(n):
        digits = "".join(rng.choice("0123456789") for _ in range(rng.randint(1, 21)))
        dot = rng.randint(0, len(digits))
        text = digits[:dot] + "." + digits[dot:] if rng.random() < 0.8 else digits
        exponent = rng.choice([None, rng.randint(-30, 30), rng.randint(-360, 330)])
        if exponent is not None:
            text += rng.choice("eE") + rng.choice(["", "+"] if exponent >= 0 else [""]) + str(exponent)
        out.append((rng.choice(["", "-", "+"]) + text).encode())
    return out


def test_random_digit_strings_and_exponents():
    tokens = _random_tokens(random.Random(0), 200_000)
    status = _assert_as_float(tokens)
    assert (status == strtod.OK).mean() > 0.85  # most are decided here, not by the exact conversion


def test_random_doubles_as_written():
    """repr and printf forms of random doubles (every exponent): all decided here but the subnormal ones."""
    rng = random.Random(1)
    tokens = []
    for _ in range(100_000):
        x = struct.unpack("<d", struct.pack("<Q", rng.getrandbits(64)))[0]
        if np.isfinite(x):
            tokens += [repr(x).encode(), b"%.17g" % x, b"%.15e" % x]
        y = rng.uniform(-10, 10)
        tokens += [repr(y).encode(), b"%.16g" % y, b"%.6f" % y]
    status = _assert_as_float(tokens)
    assert (status == strtod.OK).mean() > 0.99


def test_ties_round_to_even():
    """w·10^q exactly halfway between two doubles, w < 10^19 (q in Eisel–Lemire's round-to-even range).

    Halfway: h·2^k with h an odd 54-bit integer.  For q ≥ 0, w = r·2^j with h = r·5^q; for q < 0,
    w = h·5^−q·2^j.
    """
    rng = random.Random(2)
    tokens = []
    for _ in range(20_000):
        q = rng.randint(-4, 23)
        if q >= 0:
            lo, hi = -(-(2 ** 53) // 5 ** q), (2 ** 54 - 1) // 5 ** q
            r = rng.randint(lo, hi) | 1
            if r > hi:
                r -= 2
            w = r
        else:
            w = (rng.getrandbits(54) | (1 << 53) | 1) * 5 ** -q
        if w >= 10 ** 19:  # 19 significant digits at most are decided here
            continue
        w <<= rng.randint(0, (10 ** 19 // w).bit_length() - 1)
        tokens.append(b"%de%d" % (w, q))
    assert len(tokens) > 15_000
    values, status = _decimal(tokens)
    assert (status == strtod.OK).all()
    expected = np.array([float(t) for t in tokens])
    assert np.array_equal(_bits(values), _bits(expected))
    # they are ties: the decimal value is exactly the midpoint of two neighbouring doubles
    for t, x in zip(tokens[:500], expected[:500].tolist()):
        w, q = (int(p) for p in t.split(b"e"))
        exact = Fraction(w) * Fraction(10) ** q
        other = np.nextafter(x, np.inf if exact > Fraction(x) else -np.inf)
        assert exact - Fraction(x) == Fraction(float(other)) - exact


def test_eisel_lemire_over_its_whole_table():
    """w·10^q for random w < 2^64 and every q of the table: float's double whenever it decides."""
    rng = np.random.default_rng(3)
    n = 300_000
    w = rng.integers(1, 2 ** 63, size=n, dtype=np.uint64) * np.uint64(2) + rng.integers(0, 2, n, dtype=np.uint64)
    w >>= rng.integers(0, 64, size=n).astype(np.uint64)
    w[w == 0] = 1
    q = rng.integers(strtod.Q_MIN, strtod.Q_MAX + 1, size=n)
    values, done = _eisel_lemire_all(w, q)
    expected = np.array([float(f"{a}e{b}") for a, b in zip(w.tolist(), q.tolist())])
    assert np.array_equal(_bits(values[done]), _bits(expected[done]))
    normal = np.isfinite(expected) & (np.abs(expected) >= np.finfo(float).tiny)
    # it gives up only on subnormal or overflowing results (and, rarely, an undecidable product)
    assert done[normal].mean() > 0.999 and not done[~normal].any()


def test_the_table_is_five_to_the_q():
    """POW5[q]: the top 128 bits of 5^q for q ≥ 0; for q < 0, 2^B / 5^−q within one unit (rounded up
    where 5^−q < 2^64, q ≥ −27, which Eisel–Lemire's exact range relies on)."""
    for q in (0, 1, 27, 55, 56, 200, strtod.Q_MAX):
        hi, lo = (int(x) for x in strtod.POW5[q - strtod.Q_MIN])
        p = 5 ** q
        top = p >> max(0, p.bit_length() - 128) << max(0, 128 - p.bit_length())
        assert (hi << 64) | lo == top
    for q in (-1, -2, -13, -27, -28, -29, -100, -300, strtod.Q_MIN):
        hi, lo = (int(x) for x in strtod.POW5[q - strtod.Q_MIN])
        c, p = (hi << 64) | lo, 5 ** -q
        assert c.bit_length() == 128
        B = (c * p + p).bit_length() - 1  # c·5^−q lies within 5^−q of 2^B
        assert -p < c * p - (1 << B) <= p
        if q >= -27:
            assert 0 < c * p - (1 << B)


@pytest.mark.parametrize("token", [b"1", b"12345678", b"1.2345678901234567", b"0.12345678"])
def test_token_at_the_end_of_the_buffer(token):
    """A token with no byte after it (the last of a file without a final newline)."""
    buf = np.frombuffer(token, dtype=np.uint8)
    values, ends, status = _decimal_all(buf, np.zeros(1, dtype=np.int64))
    assert status[0] == strtod.OK and ends[0] == len(token)
    assert _bits(values[0]) == _bits(float(token))
