"""Parse the header and the element data of a PLY file (ASCII, binary little/big endian).

The reader of :mod:`.ply` turns what this returns into a mesh. Binary
elements whose rows all have the same size (scalar properties, and lists
whose counts equal those of the first row, as for triangle faces) are read
in one :func:`numpy.frombuffer` call with a structured dtype; other binary
elements and every ASCII element are read row by row, which is the
reference for every check and message. Failures raise :class:`HeaderError`
(the header) or :class:`RowError` (the data), which :mod:`.ply` words for
the user.
"""

from __future__ import annotations

import os
import re
import struct
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np

from ._common import MAX_LINE_BYTES

#: PLY type names (both spellings) and their numpy type codes.
PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_STRUCT = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I", "f4": "f", "f8": "d"}
_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
_COUNT = re.compile(r"[0-9]+")
BLOCK_BYTES = 1 << 24  # binary data is read in blocks of this size as rows need it
_HEADER_WORDS = "element, property, comment, obj_info or end_header"


class HeaderError(Exception):
    """The header cannot be read; the message names the line and the problem."""


class RowError(Exception):
    """A data row cannot be read: ``kind`` is "eof" (data ends), "eol" (row too short) or "data"."""

    def __init__(self, kind: str, detail: str):
        super().__init__(detail)
        self.kind = kind


@dataclass
class Property:
    """One property: ``dtype`` is a numpy type code; lists also have ``count_dtype``."""

    name: str
    dtype: str
    count_dtype: str | None = None

    @property
    def is_list(self) -> bool:
        return self.count_dtype is not None


@dataclass
class Element:
    name: str
    count: int
    properties: list[Property] = field(default_factory=list)


@dataclass
class Header:
    """``byte_order`` is "" for ASCII, "<" or ">" for binary; ``body`` is the data's offset."""

    byte_order: str
    elements: list[Element]
    body: int


def parse_header(head: bytes) -> Header:
    """Read the header at the start of ``head`` (which must contain all of it).

    Lines end in ``\\n`` or ``\\r\\n``; blank lines are skipped.
    """
    byte_order: str | None = None
    elements: list[Element] = []
    pos = 0
    lineno = 0
    while True:
        lineno += 1
        end = head.find(b"\n", pos)
        if end < 0:
            raise HeaderError(f"line {lineno}: early end-of-file, no 'end_header' line")
        text = head[pos:end].decode("latin-1").rstrip("\r")
        pos = end + 1
        tokens = text.split()
        if lineno == 1:
            if text != "ply":
                raise HeaderError(f"line 1: expected 'ply', found {text!r}")
            continue
        if not tokens or tokens[0] in ("comment", "obj_info"):
            continue
        word = tokens[0]
        if byte_order is None:
            byte_order = _format(lineno, tokens)
        elif word == "element":
            if len(tokens) != 3 or not _COUNT.fullmatch(tokens[2]):
                raise HeaderError(
                    f"line {lineno}: expected 'element <name> <count>' with a count >= 0, "
                    f"found {text.strip()!r}"
                )
            elements.append(Element(tokens[1], int(tokens[2])))
        elif word == "property":
            if not elements:
                raise HeaderError(f"line {lineno}: 'property' before any 'element' line")
            elements[-1].properties.append(_property(lineno, tokens, text))
        elif word == "end_header":
            return Header(byte_order, elements, pos)
        else:
            raise HeaderError(f"line {lineno}: unknown keyword {word!r} (expected {_HEADER_WORDS})")


def _format(lineno: int, tokens: list[str]) -> str:
    if tokens[0] != "format":
        raise HeaderError(
            f"line {lineno}: expected the 'format' line (or comment, obj_info), found {tokens[0]!r}"
        )
    if len(tokens) != 3 or tokens[1] not in _FORMATS:
        raise HeaderError(
            f"line {lineno}: unknown format {' '.join(tokens[1:])!r} (expected ascii, "
            "binary_little_endian or binary_big_endian, then 1.0)"
        )
    if tokens[2] != "1.0":
        raise HeaderError(f"line {lineno}: expected version '1.0', found {tokens[2]!r}")
    return _FORMATS[tokens[1]]


def _ply_type(lineno: int, name: str) -> str:
    if name not in PLY_TYPES:
        raise HeaderError(
            f"line {lineno}: unknown property type {name!r} (PLY types: {', '.join(PLY_TYPES)})"
        )
    return PLY_TYPES[name]


def _property(lineno: int, tokens: list[str], text: str) -> Property:
    if len(tokens) == 3 and tokens[1] != "list":
        return Property(tokens[2], _ply_type(lineno, tokens[1]))
    if len(tokens) == 5 and tokens[1] == "list":
        count = _ply_type(lineno, tokens[2])
        return Property(tokens[4], _ply_type(lineno, tokens[3]), count)
    raise HeaderError(
        f"line {lineno}: expected 'property <type> <name>' or "
        f"'property list <count type> <item type> <name>', found {text.strip()!r}"
    )


# --------------------------------------------------------------------------- data


def _where(element: Element, row: int, prop: Property | None = None) -> str:
    where = f"element {element.name!r}: row {row}"
    return f"{where}: property {prop.name!r}" if prop is not None else where


def _list_length(value, element: Element, row: int, prop: Property) -> int:
    """A list count as an int (PLY allows any count type; its value must be a whole number)."""
    if value != int(value) or value < 0:
        raise RowError("data", f"{_where(element, row, prop)}: list length {value!r} is invalid")
    return int(value)


class _Stream:
    """Bytes of a binary file from a position on, read in blocks as rows need them."""

    def __init__(self, fh: BinaryIO, pos: int):
        fh.seek(pos)
        self.fh, self.buf, self.off = fh, b"", 0
        self.unread = max(os.fstat(fh.fileno()).st_size - pos, 0)

    def need(self, n: int) -> bool:
        """Make ``n`` bytes from the current position available; False if the file ends first.

        A request beyond the end of the file (a corrupt count) is refused before
        anything is read or allocated.
        """
        have = len(self.buf) - self.off
        if n > have + self.unread:
            return False
        while have < n:
            more = self.fh.read(min(max(BLOCK_BYTES, n - have), self.unread))
            if not more:
                return False
            self.unread -= len(more)
            self.buf = self.buf[self.off :] + more
            self.off = 0
            have = len(self.buf)
        return True


def read_elements(fh: BinaryIO, header: Header) -> dict[str, dict]:
    """Every element's properties, reading no further into ``fh`` than the rows need.

    Parameters
    ----------
    fh : binary file
        The PLY file, opened for reading.
    header : Header
        Its header (:func:`parse_header`).

    Returns
    -------
    dict
        ``{element name: {property name: values}}`` where a scalar's values
        are an array of shape (count,) of its declared type and a list's
        are ``(items (s,), lengths (count,) int64)``. Data after the last
        declared row is never read.
    """
    out: dict[str, dict] = {}
    if header.byte_order:
        stream = _Stream(fh, header.body)
        for element in header.elements:
            out[element.name] = _binary_element(stream, element, header.byte_order)
        return out
    fh.seek(header.body)
    lines = _lines(fh)
    for element in header.elements:
        out[element.name] = _ascii_element(lines, element)
    return out


def _lines(fh: BinaryIO):
    """Lines of ``fh`` (without their end); refuses one longer than :data:`MAX_LINE_BYTES`."""
    number = 0
    while True:
        line = fh.readline(MAX_LINE_BYTES + 1)
        if not line:
            return
        number += 1
        if len(line) > MAX_LINE_BYTES:
            raise RowError("data", f"data line {number} is longer than {MAX_LINE_BYTES:,} bytes")
        yield line.rstrip(b"\n")


def _columns(element: Element, scalars: dict, lists: dict) -> dict:
    """Assemble per-property results in header order (a repeated name keeps its last column)."""
    out = {}
    for j, prop in enumerate(element.properties):
        out[prop.name] = lists[j] if prop.is_list else scalars[j]
    return out


def _binary_element(stream: _Stream, element: Element, order: str) -> dict:
    fixed = _fixed_layout(stream, element, order)
    return fixed if fixed is not None else _binary_rows(stream, element, order)


def _fixed_layout(stream: _Stream, element: Element, order: str) -> dict | None:
    """Read the element at once if every row is laid out like the first; else None."""
    if element.count == 0:
        empty = {j: np.empty(0, p.dtype) for j, p in enumerate(element.properties)}
        lists = {
            j: (np.empty(0, p.dtype), np.empty(0, np.int64))
            for j, p in enumerate(element.properties)
            if p.is_list
        }
        return _columns(element, empty, lists)
    fields, width = [], 0
    for j, prop in enumerate(element.properties):
        if prop.is_list:
            size = np.dtype(prop.count_dtype).itemsize
            if not stream.need(width + size):
                return None  # the first row is cut short: the row reader reports where
            first = np.frombuffer(stream.buf, order + prop.count_dtype, 1, stream.off + width)[0]
            if first != int(first) or first < 0:
                return None
            n = int(first)
            fields.append((f"n{j}", order + prop.count_dtype))
            fields.append((f"p{j}", order + prop.dtype, (n,)))
            width += size + n * np.dtype(prop.dtype).itemsize
            if not stream.need(width):
                return None  # a count beyond the end of the file: the row reader reports it
        else:
            fields.append((f"p{j}", order + prop.dtype))
            width += np.dtype(prop.dtype).itemsize
    dtype = np.dtype(fields)
    if dtype.itemsize == 0:
        return {}
    if not stream.need(element.count * dtype.itemsize):
        return None
    rows = np.frombuffer(stream.buf, dtype, element.count, stream.off)
    scalars, lists = {}, {}
    for j, prop in enumerate(element.properties):
        if prop.is_list:
            counts = rows[f"n{j}"]
            if not (counts == counts[0]).all():
                return None
            items = rows[f"p{j}"]
            lengths = np.full(element.count, items.shape[1], dtype=np.int64)
            lists[j] = (items.reshape(-1).astype(prop.dtype), lengths)
        else:
            scalars[j] = rows[f"p{j}"].astype(prop.dtype)
    stream.off += element.count * dtype.itemsize
    return _columns(element, scalars, lists)


def _binary_rows(stream: _Stream, element: Element, order: str) -> dict:
    """Row-by-row reader: variable-length lists, and the place where data ends."""
    props = element.properties
    scalars = {j: [] for j, p in enumerate(props) if not p.is_list}
    items = {j: [] for j, p in enumerate(props) if p.is_list}
    lengths = {j: [] for j in items}
    unpack = struct.unpack_from
    codes = [(order + _STRUCT[p.dtype], np.dtype(p.dtype).itemsize, p.count_dtype) for p in props]
    for row in range(element.count):
        for j, (prop, (code, width, count_dtype)) in enumerate(zip(props, codes)):
            if count_dtype is None:
                if not stream.need(width):
                    raise RowError("eof", f"{_where(element, row)}: early end-of-file")
                scalars[j].append(unpack(code, stream.buf, stream.off)[0])
                stream.off += width
                continue
            count_code, count_width = order + _STRUCT[count_dtype], np.dtype(count_dtype).itemsize
            if not stream.need(count_width):
                raise RowError("eof", f"{_where(element, row)}: early end-of-file")
            n = _list_length(unpack(count_code, stream.buf, stream.off)[0], element, row, prop)
            stream.off += count_width
            if not stream.need(n * width):
                raise RowError("eof", f"{_where(element, row, prop)}: early end-of-file")
            items[j].extend(unpack(f"{order}{n}{_STRUCT[prop.dtype]}", stream.buf, stream.off))
            lengths[j].append(n)
            stream.off += n * width
    done_scalars = {j: np.array(v, dtype=props[j].dtype) for j, v in scalars.items()}
    done_lists = {
        j: (np.array(items[j], dtype=props[j].dtype), np.array(lengths[j], dtype=np.int64))
        for j in items
    }
    return _columns(element, done_scalars, done_lists)


def _ascii_value(token: bytes, dtype: str, where: str):
    """One ASCII number of type ``dtype`` (Python int or float), checked against its range."""
    kind = np.dtype(dtype)
    try:
        if b"_" in token:
            raise ValueError
        if kind.kind == "f":
            return float(token)
        value = int(token)
    except ValueError:
        shown = token[:40].decode("latin-1")
        raise RowError("data", f"{where}: malformed input {shown!r}") from None
    info = np.iinfo(kind)
    if not info.min <= value <= info.max:
        raise RowError("data", f"{where}: value {value} is out of range for {kind.name}")
    return value


def _ascii_element(lines, element: Element) -> dict:
    """Row-by-row ASCII reader: one row per line, values separated by whitespace."""
    props = element.properties
    scalars = {j: [] for j, p in enumerate(props) if not p.is_list}
    items = {j: [] for j, p in enumerate(props) if p.is_list}
    lengths = {j: [] for j in items}
    for row in range(element.count):
        line = next(lines, None)
        if line is None:
            raise RowError("eof", f"{_where(element, row)}: early end-of-file")
        line.decode("ascii")  # a non-ASCII byte is reported as such
        tokens = line.split()
        k = 0
        for j, prop in enumerate(props):
            if prop.is_list:
                if k >= len(tokens):
                    raise RowError("eol", f"{_where(element, row, prop)}: early end-of-line")
                where = _where(element, row, prop)
                n = _ascii_value(tokens[k], prop.count_dtype, where)
                n = _list_length(n, element, row, prop)
                if k + 1 + n > len(tokens):
                    raise RowError("eol", f"{where}: early end-of-line")
                row_items = tokens[k + 1 : k + 1 + n]
                items[j].extend(_ascii_value(t, prop.dtype, where) for t in row_items)
                lengths[j].append(n)
                k += 1 + n
            else:
                if k >= len(tokens):
                    raise RowError("eol", f"{_where(element, row, prop)}: early end-of-line")
                scalars[j].append(_ascii_value(tokens[k], prop.dtype, _where(element, row, prop)))
                k += 1
        if k != len(tokens):
            raise RowError("data", f"{_where(element, row)}: expected end-of-line")
    done_scalars = {j: np.array(v, dtype=props[j].dtype) for j, v in scalars.items()}
    done_lists = {
        j: (np.array(items[j], dtype=props[j].dtype), np.array(lengths[j], dtype=np.int64))
        for j in items
    }
    return _columns(element, done_scalars, done_lists)
