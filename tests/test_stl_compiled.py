"""The compiled ASCII STL parser: the same numbers and meshes as the reference parsers."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from igljoin.errors import MeshReadError
from igljoin.io import _decimal, read_mesh, stl


def _facets(numbers: list[bytes]) -> bytes:
    """Plain facets holding ``numbers`` as coordinates (padded with zeros to whole facets)."""
    numbers = numbers + [b"0"] * (-len(numbers) % 9)
    out = []
    for f in range(0, len(numbers), 9):
        c = numbers[f : f + 9]
        out.append(
            b"facet normal 0 0 1\n  outer loop\n"
            + b"".join(b"    vertex %s %s %s\n" % tuple(c[3 * k : 3 * k + 3]) for k in range(3))
            + b"  endloop\nendfacet\n"
        )
    return b"".join(out)


def _decimals(count: int, seed: int = 0) -> list[bytes]:
    """Decimals of every kind a file holds: shortest reprs, %.17g, fixed, long and odd ones."""
    rng = np.random.default_rng(seed)
    out = []
    for bits in rng.integers(0, 2**63, count, dtype=np.uint64):
        x = struct.unpack("<d", struct.pack("<Q", int(bits) | int(rng.integers(2)) << 63))[0]
        if not np.isfinite(x):
            continue
        fmt = ["%r", "%.17g", "%.16g", "%.15e", "%.6f", "%.3e"][int(rng.integers(6))]
        text = (fmt % x).encode()
        if len(text.split(b"e")[0].replace(b".", b"").lstrip(b"-0")) <= 19:  # not: 1e300 as %f
            out.append(text)
    for _ in range(count):
        digits = "".join(rng.choice(list("0123456789"), int(rng.integers(1, 20))))
        out.append(f"{digits}e{int(rng.integers(-330, 310))}".encode())
        out.append(f"-{digits[:1]}.{digits[1:]}E+{int(rng.integers(0, 30))}".encode())
    out += [
        b"9007199254740993",  # 2**53 + 1: exactly halfway, rounds to even
        b"9007199254740995",
        b"3801906481570168.5",  # exact in binary, 17 digits
        b"1e23",
        b"2.2250738585072014e-308",  # the smallest normal double
        b"4.9e-324",  # subnormal: handed back to float()
        b"1.7976931348623157e308",
        b"1e-400",
        b"1e400",
        b"0e999",
        b"-0",
        b"+0.0",
        b"5.",
        b".5",
        b"-.5e-1",
        b"1.2500000",
        b"0.30000000000000004",
        b"9999999999999999999",
    ]
    return out


def test_every_coordinate_is_what_float_gives(monkeypatch):
    monkeypatch.setattr(_decimal, "RETRIES", 10**6)  # subnormals: many, all handed back
    numbers = _decimals(20000)
    body = _facets(numbers)
    corners, lines = _decimal.parse_facets(body, 0, len(body))
    want = np.array([float(x) for x in numbers] + [0.0] * (-len(numbers) % 9))
    # bit for bit: the same double, the sign of zero included
    assert np.array_equal(corners.ravel().view(np.uint64), want.view(np.uint64))
    assert lines == body.count(b"\n")


@pytest.mark.parametrize(
    "bad",
    [b"nan", b"inf", b"1_0", b"0x1p3", b"1e", b"-", b"1.2.3", b"12345678901234567890", b"1,5"],
)
def test_what_is_not_a_plain_decimal_goes_to_the_other_parsers(bad):
    body = _facets([b"1", bad, b"2"])
    assert _decimal.parse_facets(body, 0, len(body)) is None


@pytest.mark.parametrize(
    "layout",
    [
        b"FACET normal 0 0 1\nouter loop\n" + b"vertex 0 0 0\n" * 3 + b"endloop\nendfacet\n",
        b"facet normal 0 0 1 outer loop\n" + b"vertex 0 0 0\n" * 3 + b"endloop\nendfacet\n",
        b"facet normal 0 0 1\nouter loop\n" + b"vertex 0 0 0 " * 3 + b"\nendloop\nendfacet\n",
        b"facet normal 0 0\nouter loop\n" + b"vertex 0 0 0\n" * 3 + b"endloop\nendfacet\n",
        b"facet normal 0 0 1\nouter loop\n" + b"vertex 0 0 0\n" * 2 + b"endloop\nendfacet\n",
        b"facet normal 0 0 1\x0b\nouter loop\n" + b"vertex 0 0 0\n" * 3 + b"endloop\nendfacet\n",
    ],
    ids=["case", "outer-on-facet-line", "two-vertices-on-a-line", "short-normal", "two-vertices",
         "odd-space"],
)  # fmt: skip
def test_other_layouts_go_to_the_other_parsers(layout):
    assert _decimal.parse_facets(layout, 0, len(layout)) is None


def test_full_retry_list_hands_the_block_back(monkeypatch):
    monkeypatch.setattr(_decimal, "RETRIES", 1)
    body = _facets([b"4.9e-324", b"-1e-310"])  # subnormals: converted by float()
    assert _decimal.parse_facets(body, 0, len(body)) is None
    monkeypatch.setattr(_decimal, "RETRIES", 2)
    corners, _ = _decimal.parse_facets(body, 0, len(body))
    assert corners[0, 0] == 5e-324 and corners[0, 1] == float("-1e-310")


@pytest.mark.parametrize("indent", [b"", b"  ", b"\t"])
def test_read_mesh_gives_the_reference_mesh(tmp_path, monkeypatch, indent):
    numbers = _decimals(300, seed=1)[:270]
    text = b"solid t\n" + _facets(numbers).replace(b"  ", indent) + b"endsolid t\n"
    path = tmp_path / "t.stl"
    path.write_bytes(text)
    monkeypatch.setattr(stl, "COMPILED_BYTES", 0)
    compiled = read_mesh(path)
    monkeypatch.setattr(stl, "_fast", lambda *args: False)  # the line-by-line reference
    reference = read_mesh(path)
    assert np.array_equal(compiled.V, reference.V)
    assert np.array_equal(compiled.F, reference.F)


def test_messages_after_a_compiled_block_name_the_right_line(tmp_path, monkeypatch):
    facet = _facets([b"1", b"2", b"3", b"4", b"5", b"6", b"7", b"8", b"9.5"])
    path = tmp_path / "t.stl"
    path.write_bytes(b"solid t\n" + facet * 3 + b"  vertex 1 2 3\nendsolid t\n")
    monkeypatch.setattr(stl, "COMPILED_BYTES", 0)
    with pytest.raises(MeshReadError, match=r"line 23: 'vertex' outside a facet"):
        read_mesh(path)
