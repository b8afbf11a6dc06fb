"""Compiled parsing of plain ASCII STL facets, with correctly rounded decimal conversion.

The ASCII STL reader hands each block of facets here first. :func:`parse_facets`
walks the bytes once: it checks that the tokens are exactly
``facet normal a b c outer loop vertex x y z (x3) endloop endfacet``, with
``outer``, each ``vertex`` and ``endloop`` first on their lines (as the
line-by-line reference parser reads them), and converts the nine coordinates
of each facet to float64. It gives up (and the reader falls back to its other
parsers, which give every message) on anything else: other keywords or letter
case, other whitespace than space, tab and ``\\n``, a coordinate that is not
a plain decimal (``nan``, ``inf``, ``1_0``, more than 19 significant digits).
Subnormal and overflowing values are converted by ``float``.

Conversion of ``w * 10**q`` (``w`` the up to 19 significant digits as an
integer) is exact where ``w < 2**53`` and ``|q| <= 22`` (both are exact
doubles and IEEE arithmetic rounds once). Otherwise ``w`` is multiplied by a
128-bit truncation of ``5**q`` (exact for ``0 <= q <= 55``): the top 64 bits of
the product decide the rounding unless the bits below the rounding bit lie
at a rounding boundary, where the full 192-bit product is formed; the true
product lies less than ``2**64`` above it, so only a product at a boundary
within that margin stays open (a dyadic value ``w / 5**-q * 2**q`` is then
converted exactly; anything else, about one random decimal in ``2**54``, is
handed back and converted by Python's ``float``).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

#: Numbers per block whose rounding the 128-bit product leaves open (about one in 2**54
#: of random decimals; more: the block goes to the other parsers).
RETRIES = 1000
#: Range of decimal exponents with a table entry (beyond it: 0 or overflow, left to ``float``).
Q_MIN, Q_MAX = -342, 308


def _power_table() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``5**q`` as ``(hi * 2**64 + lo) * 2**e`` with ``2**127 <= hi * 2**64 + lo < 2**128``.

    Returns
    -------
    hi, lo : ndarray of uint64, shape (Q_MAX - Q_MIN + 1,)
        The 128-bit mantissa, truncated (never above the true value).
    e : ndarray of int64, shape (Q_MAX - Q_MIN + 1,)
        Its binary exponent.
    """
    hi, lo, ex = [], [], []
    for q in range(Q_MIN, Q_MAX + 1):
        if q >= 0:
            p = 5**q
            e = p.bit_length() - 128
            m = p >> e if e >= 0 else p << -e
        else:
            d = 5**-q
            s = d.bit_length()
            m = (1 << (127 + s)) // d
            e = -(127 + s)
        hi.append(m >> 64)
        lo.append(m & (2**64 - 1))
        ex.append(e)
    return np.array(hi, dtype=np.uint64), np.array(lo, dtype=np.uint64), np.array(ex, np.int64)


# The compiled functions read this module's tables as constants (numba freezes global arrays
# when it compiles): passed as arguments, each would cost reference counting per number.
HI, LO, EX = _power_table()

u64 = np.uint64
MASK32 = u64(0xFFFFFFFF)
ALL = u64(0xFFFFFFFFFFFFFFFF)
ONE = u64(1)
TOP = u64(1 << 63)
TWO52, TWO53 = u64(1 << 52), u64(1 << 53)
#: The powers of five below 2**64.
POW5 = np.array([5**k for k in range(28)], dtype=np.uint64)
#: 2**-1074 ... 2**971: the scales of normal doubles with a 53-bit integer mantissa.
POW2 = np.ldexp(1.0, np.arange(-1074, 972))
#: The powers of ten that are exact doubles.
EXACT = np.array([10.0**k for k in range(23)])


@nb.njit(cache=True, inline="always")
def mul(a, b):
    """Full 64 x 64 -> 128-bit product as (high, low)."""
    a0, a1 = a & MASK32, a >> u64(32)
    b0, b1 = b & MASK32, b >> u64(32)
    p00, p01, p10, p11 = a0 * b0, a0 * b1, a1 * b0, a1 * b1
    mid = (p00 >> u64(32)) + (p01 & MASK32) + (p10 & MASK32)
    low = (p00 & MASK32) | (mid << u64(32))
    high = p11 + (p01 >> u64(32)) + (p10 >> u64(32)) + (mid >> u64(32))
    return high, low


@nb.njit(cache=True, inline="always")
def convert(w, q, negative):
    """``(-1)**negative * w * 10**q`` correctly rounded, and whether that was decided."""
    if w == u64(0):
        return (-0.0 if negative else 0.0), True
    while w % u64(10) == u64(0):  # 1.2500 is 125e-2
        w = w // u64(10)
        q += 1
    if w <= TWO53 and -22 <= q <= 22:
        x = float(w)
        x = x * EXACT[q] if q >= 0 else x / EXACT[-q]
        return (-x if negative else x), True
    if q < Q_MIN or q > Q_MAX:
        return 0.0, False
    given = w
    lz = 0
    for step in (32, 16, 8, 4, 2, 1):  # normalise: the top bit of w set
        if w < (ONE << u64(64 - step)):
            w = w << u64(step)
            lz += step
    k = q - Q_MIN
    H, L = mul(w, HI[k])
    up = int(H >> u64(63))
    shift = u64(9 + up)
    m54 = H >> shift
    R = H & ((ONE << shift) - ONE)
    # The exact product lies in [H * 2**128 + L * 2**64, that + 2**128): w * LO[k] adds less
    # than 2**128, and so does the truncation of 5**q unless it is exact (0 <= q <= 55).
    # Unless R is all ones (a carry could reach the rounding bit) or the rounding bit is set
    # over zeros (maybe halfway), that leaves the result decided.
    rest = L
    if R == (ONE << shift) - ONE or ((m54 & ONE) and R == u64(0) and L == u64(0)):
        b1, b0 = mul(w, LO[k])
        L = L + b1
        H = H + (ONE if L < b1 else u64(0))
        # now the exact product is H * 2**128 + L * 2**64 + b0, plus less than 2**64 unless
        # exact (the carry may have set the top bit of H)
        up = int(H >> u64(63))
        shift = u64(9 + up)
        m54 = H >> shift
        R = H & ((ONE << shift) - ONE)
        exact = 0 <= q <= 55
        if not exact and (
            (R == (ONE << shift) - ONE and L == ALL)  # a carry could reach the rounding bit
            or ((m54 & ONE) and R == u64(0) and L == u64(0) and b0 == u64(0))  # maybe halfway
        ):
            if -27 <= q < 0 and given % POW5[-q] == u64(0):  # dyadic: given / 5**-q * 2**q
                x = math.ldexp(float(given // POW5[-q]), q)  # the integer rounds once
                return (-x if negative else x), True
            return 0.0, False
        rest = L | b0
    mant = m54 >> ONE
    if m54 & ONE:  # halfway or above
        mant += ONE if (R != u64(0) or rest != u64(0)) else mant & ONE
    exponent = 129 + int(shift) + q - lz + int(EX[k])
    if mant == TWO53:
        mant = TWO52
        exponent += 1
    if exponent < -1074 or exponent > 971:
        return 0.0, False  # subnormal or overflow: left to float()
    x = float(mant) * POW2[exponent + 1074]  # exact: a normal double times a power of two
    return (-x if negative else x), True


@nb.njit(cache=True, inline="always")
def digits(b, i, n, w, kept):
    """Append the decimal digits at ``b[i:]`` to ``w``; (w, digits kept, index after them).

    Leading zeros of ``w`` are not counted; more than 19 digits make ``kept`` exceed 19.
    """
    while i < n:
        d = np.int64(b[i]) - 48
        if d < 0 or d > 9:
            break
        w = w * u64(10) + u64(d)
        kept += 1 if (kept or d) else 0
        i += 1
    return w, kept, i


@nb.njit(cache=True, inline="always")
def number(b, i, n):
    """Parse the plain decimal at ``b[i:]``; (value, decided, index after it, ok)."""
    negative = b[i] == 45
    if b[i] == 45 or b[i] == 43:  # - +
        i += 1
    first = i
    w, kept, i = digits(b, i, n, u64(0), 0)
    whole = i - first
    q = 0
    if i < n and b[i] == 46:  # .
        i += 1
        fraction = i
        w, kept, i = digits(b, i, n, w, kept)
        q = fraction - i
        whole += i - fraction
    if whole == 0 or kept > 19:
        return 0.0, False, i, False
    if i < n and (b[i] == 101 or b[i] == 69):  # e E
        i += 1
        sign = 1
        if i < n and (b[i] == 45 or b[i] == 43):
            sign = -1 if b[i] == 45 else 1
            i += 1
        e = 0
        first = i
        while i < n and 48 <= b[i] <= 57:
            if e < 100000:
                e = e * 10 + (b[i] - 48)
            i += 1
        if i == first:
            return 0.0, False, i, False
        q += sign * e
    if i < n and not (b[i] == 32 or b[i] == 9 or b[i] == 10):
        return 0.0, False, i, False
    x, decided = convert(w, q, negative)
    return x, decided, i, True


#: What each of the 21 tokens of a facet is: a keyword (its bytes in WORDS, its length in
#: LENGTHS), -1 any token (the normal, which the reader ignores), -2 a coordinate.
LAYOUT = (
    "facet normal - - - outer loop vertex + + + vertex + + + vertex + + + endloop endfacet"
).split()
WORDS = np.zeros((21, 8), dtype=np.uint8)
LENGTHS = np.zeros(21, dtype=np.int64)
for _k, _token in enumerate(LAYOUT):
    if _token == "-":
        LENGTHS[_k] = -1
    elif _token == "+":
        LENGTHS[_k] = -2
    else:
        WORDS[_k, : len(_token)] = np.frombuffer(_token.encode(), dtype=np.uint8)
        LENGTHS[_k] = len(_token)
#: Tokens that the reference parser reads as the first of a line (its keys).
LINE_FIRST = np.array([t in ("outer", "vertex", "endloop") for t in LAYOUT])
#: Where each coordinate token goes among the nine of its facet (-1: not a coordinate).
SLOT = np.full(21, -1, dtype=np.int64)
SLOT[[k for k, t in enumerate(LAYOUT) if t == "+"]] = np.arange(9)


@nb.njit(cache=True, nogil=True)  # blocks are parsed on several threads at once
def facets(b, i, n, out, retry):
    """Parse the facets of ``b[i:n]`` into ``out`` (9 per facet); their number (-1: not
    plain facets) and the line breaks."""
    t = 0  # the token's place in its facet
    count = 0
    lines = 0
    while True:
        newline = False
        while i < n and (b[i] == 32 or b[i] == 9 or b[i] == 10):
            if b[i] == 10:
                newline = True
                lines += 1
            i += 1
        if i == n:
            break
        if LINE_FIRST[t] and not newline:
            return -1, 0
        m = LENGTHS[t]
        if m > 0:  # a keyword
            if i + m > n:
                return -1, 0
            for j in range(m):
                if b[i + j] != WORDS[t, j]:
                    return -1, 0
            i += m
            if i < n and not (b[i] == 32 or b[i] == 9 or b[i] == 10):
                return -1, 0
        elif m == -1:  # any token
            while i < n and not (b[i] == 32 or b[i] == 9 or b[i] == 10):
                if b[i] < 32 or b[i] == 0x85 or b[i] == 0xA0:
                    return -1, 0  # whitespace to Python (or a control byte): the reference decides
                i += 1
        else:  # a coordinate
            if 9 * count + 9 > out.size:
                return -1, 0
            at = 9 * count + SLOT[t]
            first = i
            x, decided, i, ok = number(b, i, n)
            if not ok:
                return -1, 0
            out[at] = x
            if not decided:  # converted by float() afterwards
                r = retry[0]
                if 3 * r + 4 > retry.size:
                    return -1, 0
                retry[3 * r + 1] = at
                retry[3 * r + 2] = first
                retry[3 * r + 3] = i
                retry[0] = r + 1
        t += 1
        if t == 21:
            t = 0
            count += 1
    return count if t == 0 else -1, lines


def parse_facets(data: bytes, start: int, stop: int) -> tuple[np.ndarray, int] | None:
    """The corners of the plain ASCII STL facets in ``data[start:stop]``, or None.

    Parameters
    ----------
    data : bytes
        A block of the file.
    start, stop : int
        The span holding whole facets only (``facet`` ... ``endfacet``), or
        the result is None.

    Returns
    -------
    (corners, lines) or None
        ``corners`` of shape (3 t, 3), float64: three per facet, each
        coordinate the nearest double to its decimal (as ``float`` gives
        it); ``lines``, the line breaks in the span. None if the span holds
        anything else, or a byte that Python counts as whitespace other than
        space, tab and ``\\n``.
    """
    b = np.frombuffer(data, dtype=np.uint8)
    out = np.empty(9 * ((stop - start) // 40 + 1))  # a facet takes more than 40 bytes
    retry = np.zeros(1 + 3 * RETRIES, dtype=np.int64)
    count, lines = facets(b, start, stop, out, retry)
    if count < 0:
        return None
    for at, first, end in retry[1:].reshape(-1, 3)[: retry[0]]:
        out[at] = float(data[first:end])
    return out[: 9 * count].reshape(-1, 3), lines
