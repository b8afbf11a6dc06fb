"""The compiled ASCII STL parser: the same numbers and meshes as the reference parsers."""

from __future__ import annotations

import struct
import threading

import numpy as np
import pytest

from igljoin.errors import MeshReadError
from igljoin.io import _common, _decimal, read_mesh, stl


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


def _reference_outcome(path, monkeypatch):
    """What the line-by-line reference parser gives: the mesh, or the error message."""
    with monkeypatch.context() as m:
        m.setattr(stl, "_fast", lambda *args: False)
        return _outcome(path)


def _outcome(path):
    try:
        mesh = read_mesh(path)
    except MeshReadError as exc:
        return str(exc)
    return mesh.V, mesh.F


def _many_blocks(monkeypatch, threads) -> list[str]:
    """Blocks of a few facets each, all compiled, parsed on ``threads`` threads; the list
    receives the name of the thread of each compiled parse."""
    monkeypatch.setattr(_common, "CHUNK_BYTES", 4096)  # about ten facets a block
    monkeypatch.setattr(stl, "COMPILED_BYTES", 0)
    monkeypatch.setattr(stl, "THREADS", threads)
    names = []
    parse = _decimal.parse_facets

    def counted(*args):
        names.append(threading.current_thread().name)
        return parse(*args)

    monkeypatch.setattr(_decimal, "parse_facets", counted)
    return names


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_blocks_parsed_on_threads_give_the_reference_mesh(tmp_path, monkeypatch, threads):
    finite = [x for x in _decimals(400, seed=2) if np.isfinite(float(x))]
    pool = [finite[3 * k : 3 * k + 3] for k in range(50)]  # 50 corners, shared by facets
    rng = np.random.default_rng(3)
    numbers = [x for k in rng.integers(0, len(pool), 3 * 100) for x in pool[k]]
    path = tmp_path / "t.stl"
    path.write_bytes(b"solid t\n" + _facets(numbers) + b"endsolid t\n")
    names = _many_blocks(monkeypatch, threads)
    V, F = _outcome(path)
    # many blocks, all compiled, on pool threads unless one thread is asked for
    assert len(names) > 5
    assert all(name.startswith("igljoin-stl") == (threads > 1) for name in names)
    want_V, want_F = _reference_outcome(path, monkeypatch)
    assert F.shape[0] == 100 and V.shape[0] <= 50
    # bit for bit, the same vertices in the same order
    assert np.array_equal(V.view(np.uint64), want_V.view(np.uint64))
    assert np.array_equal(F, want_F)


BAD_TAILS = {
    # a facet of two vertices: the compiled parser hands its block back, the reference reports
    "two-vertices": b"facet normal 0 0 1\n  outer loop\n" + b"    vertex 0 0 0\n" * 2
    + b"  endloop\nendfacet\n",
    "vertex-outside": b"  vertex 1 2 3\n",
    "bad-number": b"facet normal 0 0 1\n  outer loop\n    vertex 0 0 x\n",
}  # fmt: skip


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("bad", sorted(BAD_TAILS))
def test_a_bad_block_after_parallel_ones_names_the_right_line(tmp_path, monkeypatch, threads, bad):
    facet = _facets([b"1", b"2", b"3", b"4", b"5", b"6", b"7", b"8", b"9.5"])
    path = tmp_path / "t.stl"
    path.write_bytes(b"solid t\n" + facet * 60 + BAD_TAILS[bad] + facet * 60 + b"endsolid t\n")
    _many_blocks(monkeypatch, threads)
    message = _outcome(path)
    assert message == _reference_outcome(path, monkeypatch)
    # after the header line and 60 facets of 7 lines, on the bad tail's line the message names
    offset = {"two-vertices": 4, "vertex-outside": 0, "bad-number": 2}[bad]
    assert f"line {2 + 60 * 7 + offset}:" in message


@pytest.mark.parametrize("threads", [1, 2])
def test_errors_met_while_reading_ahead_come_in_file_order(tmp_path, monkeypatch, threads):
    facet = _facets([b"1", b"2", b"3", b"4", b"5", b"6", b"7", b"8", b"9.5"])
    path = tmp_path / "t.stl"
    bad = b"  vertex 1 2 3\n"
    # a bad line, then (blocks later, already read when that block is parsed) a NUL byte
    path.write_bytes(b"solid t\n" + facet * 30 + bad + facet * 30 + b"\0" + facet)
    _many_blocks(monkeypatch, threads)
    assert f"line {2 + 30 * 7}: 'vertex' outside a facet" in _outcome(path)
    # a line too long after compiled blocks: its number counts their lines
    path.write_bytes(b"solid t\n" + facet * 30 + b"x" * 20000 + b"\n" + facet + b"endsolid t\n")
    monkeypatch.setattr(_common, "MAX_LINE_BYTES", 8192)
    assert f"line {2 + 30 * 7} is longer than 8,192 bytes" in _outcome(path)


def test_a_carriage_return_before_the_facets_counts_as_the_reference_counts(tmp_path, monkeypatch):
    facet = _facets([b"1", b"2", b"3", b"4", b"5", b"6", b"7", b"8", b"9.5"])
    path = tmp_path / "t.stl"
    path.write_bytes(b"solid t\r\r\n" + facet * 3 + b"  vertex 1 2 3\nendsolid t\n")
    monkeypatch.setattr(stl, "COMPILED_BYTES", 0)
    message = _outcome(path)
    assert message == _reference_outcome(path, monkeypatch)
    assert "line 24: 'vertex' outside a facet" in message  # 'solid t', '', 3 facets of 7 lines
