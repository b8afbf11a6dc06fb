"""Reader and writer guards: bad files refused with igljoin errors before memory is spent.

Huge inputs are sparse files (a 40 GB file costs no disk), so each test
shows the reader refuses from the header or the first block, not by reading
the whole file; the process-level test bounds address space and time.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import igljoin.mesh
from igljoin.errors import MeshError, MeshReadError
from igljoin.io import _common, read_mesh, write_mesh
from igljoin.mesh import Mesh

GB = 2**30
TRIANGLE_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"


def _sparse(path: Path, head: bytes, size: int) -> Path:
    """``head`` followed by zero bytes up to ``size`` (a sparse file: no disk is used)."""
    with open(path, "wb") as fh:
        fh.write(head)
        fh.truncate(size)
    return path


def _message(path) -> str:
    with pytest.raises(MeshReadError) as info:
        read_mesh(path)
    return str(info.value)


# --------------------------------------------------------------------------- issue items


def test_ascii_stl_vertex_outside_a_loop(tmp_path):
    """A vertex count that is not a multiple of 3 used to end in numpy's 'cannot reshape'."""
    path = tmp_path / "stray.stl"
    path.write_text(
        "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
        "endloop\nendfacet\nvertex 1 1 1\nendsolid s\n"
    )
    assert _message(path) == (
        f"{path}: line 9: 'vertex' outside a facet's 'outer loop'; "
        "the file is corrupt; re-export it"
    )
    only = tmp_path / "only_vertices.stl"
    only.write_text("solid s\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nvertex 1 1 0\nendsolid\n")
    assert "line 2: 'vertex' outside a facet's 'outer loop'" in _message(only)


def test_ascii_stl_loop_without_endloop(tmp_path):
    path = tmp_path / "open_loop.stl"
    path.write_text(
        "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
        "outer loop\nvertex 0 1 0\nvertex 0 0 0\nvertex 1 0 0\nendloop\nendfacet\nendsolid s\n"
    )
    assert _message(path) == (
        f"{path}: line 6: 'outer loop' before the facet begun on line 3 has its 'endloop'; "
        "the file is truncated or corrupt; re-export it"
    )


@pytest.mark.parametrize("index", [2**63, -(2**63) - 1, 10**40])
def test_off_face_index_beyond_int64(tmp_path, index):
    """Used to raise OverflowError from numpy."""
    path = tmp_path / "big_index.off"
    path.write_text(f"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 {index}\n")
    assert _message(path) == (
        f"{path}: line 6: face references vertex {index}, far beyond any vertex count; "
        "the file is corrupt; re-export it"
    )


def test_bytes_path_reads_like_a_str_path(tmp_path):
    path = tmp_path / "t.obj"
    path.write_text(TRIANGLE_OBJ)
    by_bytes = read_mesh(os.fsencode(path))
    np.testing.assert_array_equal(by_bytes.V, read_mesh(path).V)
    assert by_bytes.name == "t"
    out = write_mesh(os.fsencode(tmp_path / "copy.ply"), by_bytes)
    assert out == tmp_path / "copy.ply" and read_mesh(out).n_faces == 1


@pytest.mark.parametrize(
    "bad, expected",
    [
        (None, "read_mesh needs a file path (str, bytes or os.PathLike), not NoneType"),
        (12, "read_mesh needs a file path (str, bytes or os.PathLike), not int"),
        ("a\0b.obj", "read_mesh: the path 'a\\x00b.obj' contains a NUL byte"),
    ],
)
def test_paths_that_are_not_paths(bad, expected):
    with pytest.raises(MeshReadError) as info:
        read_mesh(bad)
    assert str(info.value).startswith(expected)


def test_binary_stl_beyond_float32_is_refused_before_writing(tmp_path):
    """Used to succeed with a numpy overflow warning and write a file that cannot be read."""
    mesh = Mesh([[0, 0, 0], [1e39, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    target = tmp_path / "huge.stl"
    with pytest.raises(MeshError) as info:
        write_mesh(target, mesh)
    assert str(info.value) == (
        f"cannot write {target}: coordinates reach 1e+39, beyond the float32 range of binary "
        "STL (3.4e+38); write ASCII STL (binary=False) or PLY, or rescale the mesh"
    )
    assert list(tmp_path.iterdir()) == []
    back = read_mesh(write_mesh(target, mesh, binary=False))
    np.testing.assert_array_equal(back.V, mesh.V)


# --------------------------------------------------------------------------- declared counts


def test_headers_declaring_more_than_the_size_guard(tmp_path):
    """Counts are checked against MAX_ELEMENTS before any data is read (files are sparse)."""
    n = igljoin.mesh.MAX_ELEMENTS + 1
    off = _sparse(tmp_path / "big.off", f"OFF\n{n} 1 0\n".encode(), 8 * GB)
    assert _message(off) == (
        f"{off}: header declares 20,000,001 vertices, more than the size guard of 20,000,000; "
        "decimate the mesh or raise igljoin.mesh.MAX_ELEMENTS"
    )
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    ply = _sparse(tmp_path / "big.ply", header.encode(), 8 * GB)
    assert _message(ply) == (
        f"{ply}: header declares 20,000,001 'vertex' rows, more than the size guard of "
        "20,000,000; decimate the mesh or raise igljoin.mesh.MAX_ELEMENTS"
    )
    head = b"x" * 80 + np.array([n], dtype="<u4").tobytes()
    stl = _sparse(tmp_path / "big.stl", head, 84 + 50 * n)  # exactly a binary STL's size
    assert _message(stl) == (
        f"{stl}: binary STL header declares 20,000,001 triangles, more than the size guard of "
        "20,000,000; decimate the mesh or raise igljoin.mesh.MAX_ELEMENTS"
    )


def test_off_counts_that_cannot_fit_in_the_file(tmp_path):
    path = tmp_path / "short.off"
    path.write_text("OFF\n1000 2000 0\n0 0 0\n")
    assert _message(path) == (
        f"{path}: declares 1000 vertices and 2000 faces, which take at least 22000 bytes, but "
        "the file has only 22 bytes; the file is truncated; re-export or re-download the file"
    )


def test_text_readers_stop_at_the_size_guard(tmp_path, monkeypatch):
    """The guard trips while reading: what follows (here a 8 GB hole) is never read."""
    monkeypatch.setattr(igljoin.mesh, "MAX_ELEMENTS", 1000)
    monkeypatch.setattr(_common, "CHUNK_BYTES", 4096)
    rows = "".join(f"v {i} 0 0\n" for i in range(1001)) + "f 1 2 3\n"
    obj = _sparse(tmp_path / "many.obj", rows.encode(), 8 * GB)
    assert _message(obj) == (
        f"{obj}: line 1001: more than 1,000 vertices, the size guard; reading stopped there; "
        "decimate the mesh or raise igljoin.mesh.MAX_ELEMENTS"
    )
    faces = "v 0 0 0\nv 1 0 0\nv 0 1 0\n" + "f 1 2 3\n" * 1001
    obj2 = _sparse(tmp_path / "many_faces.obj", faces.encode(), 8 * GB)
    assert "line 1004: more than 1,000 triangles, the size guard" in _message(obj2)
    facet = "facet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\n"
    text = "solid s\n" + (facet + "endfacet\n") * 1001
    stl = _sparse(tmp_path / "many.stl", text.encode(), 8 * GB)
    # the first vertex of facet 1001: 1 solid line, 1000 facets of 7 lines, then 3 lines
    assert "line 7004: more than 1,000 triangles, the size guard" in _message(stl)


def test_endless_line_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(_common, "MAX_LINE_BYTES", 1 << 16)
    monkeypatch.setattr(_common, "CHUNK_BYTES", 1 << 14)
    path = tmp_path / "one_line.obj"
    path.write_bytes(b"v 0 0 0\n# " + b"x" * (1 << 17))
    assert _message(path) == (
        f"{path}: line 2 is longer than 65,536 bytes; the file is corrupt or not an OBJ file; "
        "re-export it"
    )


# --------------------------------------------------------------------------- 40 GB, bounded


def test_40_gb_files_are_refused_in_bounded_memory_and_time(tmp_path):
    """In a process limited to 2 GiB of address space each 40 GB file is refused at once.

    Reading any of them whole (what the readers did) would fail with
    MemoryError there; the 120 s timeout bounds a reader that scanned on.
    """
    files = {
        "zeros.obj": b"",
        "zeros.off": b"",
        "zeros.stl": b"",
        "zeros.ply": b"",
        "after.obj": TRIANGLE_OBJ.encode(),
        "after.off": b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
        "after.stl": b"solid s\n",
        "after.ply": (
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            b"property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
            b"end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
        ),
    }
    for name, head in files.items():
        _sparse(tmp_path / name, head, 40 * GB)
    script = textwrap.dedent(
        f"""
        import json, resource, sys
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
        from igljoin.io import read_mesh
        out = {{}}
        for name in {sorted(files)!r}:
            try:
                read_mesh({str(tmp_path)!r} + "/" + name)
                out[name] = "read"
            except Exception as exc:
                out[name] = type(exc).__name__ + ": " + str(exc).split(": ", 1)[1]
        print(json.dumps(out))
        """
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parent.parent)}
    proc = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=env
    )
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    binary = "MeshReadError: contains binary data (NUL bytes) but {} files are plain text"
    assert got["zeros.obj"].startswith(binary.format("OBJ"))
    assert got["zeros.off"].startswith(binary.format("OFF"))
    assert got["after.obj"].startswith(binary.format("OBJ"))
    assert got["after.off"].startswith(binary.format("OFF"))
    stl = (
        "MeshReadError: binary STL header declares 0 triangles (84 bytes) but the file has "
        "42949672960 bytes; it is truncated or not an STL file"
    )
    assert got["zeros.stl"].startswith(stl)
    assert got["after.stl"].startswith(stl)  # "solid" then NUL bytes: not ASCII STL
    assert got["zeros.ply"].startswith("MeshReadError: does not start with the 'ply' magic line")
    # a valid ASCII PLY followed by 40 GB of zeros: the rows its header declares are read and
    # what follows is never looked at (as in other PLY readers), within the memory bound
    assert got["after.ply"] == "read"
