"""igljoin's own PLY reader: every type and byte order, real files against pymeshlab, bad files.

pymeshlab (VCG's PLY reader) is the independent reference for real files:
the sample meshes it ships, and PLY files its writer makes of real OBJ
samples (binary and ASCII, with face colours and per-corner texture
coordinates, a list property of floats).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pymeshlab
import pytest

from igljoin.errors import MeshReadError
from igljoin.io import _ply_parse, read_mesh, write_mesh
from igljoin.mesh import Mesh

SAMPLES = Path(pymeshlab.__file__).parent / "tests" / "sample_meshes"
TYPES = ("char", "uchar", "short", "ushort", "int", "uint", "float", "double")
NUMPY = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4"}
NUMPY |= {"float": "f4", "double": "f8"}


def _pymeshlab(path: Path) -> pymeshlab.MeshSet:
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    return ms


def _assert_like_pymeshlab(path: Path) -> Mesh:
    """V and F exactly as pymeshlab reads them; colours and quality too where the file has them."""
    ms = _pymeshlab(path)  # the mesh lives as long as its MeshSet
    mesh, reference = read_mesh(path), ms.current_mesh()
    # pymeshlab holds doubles; files store float32 or float64, both exact in double
    np.testing.assert_array_equal(mesh.V, reference.vertex_matrix())
    np.testing.assert_array_equal(mesh.F, reference.face_matrix())
    for attrs, colours, kind in (
        (mesh.vertex_attributes, reference.vertex_color_matrix, "vertex"),
        (mesh.face_attributes, reference.face_color_matrix, "face"),
    ):
        if "red" in attrs:
            rgba = np.column_stack([attrs[c] for c in ("red", "green", "blue", "alpha")])
            # pymeshlab gives colour bytes divided by 255 as doubles: the rounding is exact
            np.testing.assert_array_equal(np.round(colours() * 255), rgba, err_msg=kind)
    if "quality" in mesh.vertex_attributes:
        # VCG keeps quality as float64 here; the files hold float32 or float64 values
        np.testing.assert_array_equal(
            mesh.vertex_attributes["quality"], reference.vertex_scalar_array()
        )
    return mesh


@pytest.mark.parametrize("name", ["bone.ply", "colored_airplane.ply", "rangemaps/face000.ply"])
def test_sample_plys_read_as_pymeshlab_reads_them(name):
    mesh = _assert_like_pymeshlab(SAMPLES / name)
    assert mesh.n_faces > 3000  # the real meshes, not an empty element


@pytest.mark.parametrize("name", ["bunny.obj", "cow.obj", "bunny10k_textured.obj"])
@pytest.mark.parametrize("binary", [True, False])
def test_plys_written_by_pymeshlab_read_as_pymeshlab_reads_them(tmp_path, name, binary):
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(SAMPLES / name))
    path = tmp_path / "m.ply"
    ms.save_current_mesh(str(path), binary=binary, save_face_color=True)
    header = path.read_bytes().split(b"end_header")[0]
    assert (b"binary_little_endian" in header) == binary
    mesh = _assert_like_pymeshlab(path)
    assert mesh.n_faces == ms.current_mesh().face_number()
    if name == "bunny10k_textured.obj":  # faces carry a list of floats before their colour
        assert b"property list uchar float texcoord" in header
        assert set(mesh.face_attributes) == {"red", "green", "blue", "alpha"}


# --------------------------------------------------------------------------- types, byte orders


QUADS = [[0, 1, 2, 3], [0, 2, 3]]
TRIANGLES = [[0, 1, 2], [0, 2, 3]]


def _typed_file(order: str, vtype: str, count: str, index: str, faces: list) -> bytes:
    """A 4-vertex PLY with properties of ``vtype``, ``faces`` indexed by ``index``."""
    fmt = {"<": "binary_little_endian", ">": "binary_big_endian", "": "ascii"}[order]
    header = (
        f"ply\nformat {fmt} 1.0\ncomment every type\nelement vertex 4\nproperty {vtype} x\n"
        f"property {vtype} y\nproperty double z\nproperty {vtype} value\n"
        f"property list uchar {vtype} extra\nelement face {len(faces)}\nproperty {vtype} before\n"
        f"property list {count} {index} vertex_indices\nproperty {vtype} after\n"
        "element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n"
    )
    V = [[0, 0, 0.25], [1, 0, -0.5], [1, 1, 1e300], [0, 1, -0.0]]
    value = [0, 1, 100, 127]  # fits every PLY type
    if not order:
        rows = [f"{x} {y} {z!r} {v} {k} " + " 7" * k for (x, y, z), v, k in zip(V, value, range(4))]
        rows += [f"{5 + j} {len(f)} {' '.join(map(str, f))} {9 - j}" for j, f in enumerate(faces)]
        return (header + "\n".join([*rows, "0 1"]) + "\n").encode()
    t = order + NUMPY[vtype]
    body = b""
    for (x, y, z), v, k in zip(V, value, range(4)):
        body += np.array([x, y], t).tobytes() + np.array(z, order + "f8").tobytes()
        body += np.array(v, t).tobytes() + bytes([k]) + np.full(k, 7, t).tobytes()
    for j, f in enumerate(faces):
        body += np.array(5 + j, t).tobytes() + np.array(len(f), order + NUMPY[count]).tobytes()
        body += np.array(f, order + NUMPY[index]).tobytes() + np.array(9 - j, t).tobytes()
    return header.encode() + body + np.array([0, 1], order + "i4").tobytes()


@pytest.mark.parametrize("order", ["<", ">", ""])
@pytest.mark.parametrize("vtype", TYPES)
def test_every_type_and_byte_order(tmp_path, order, vtype):
    """Scalars of every type, lists skipped, any count/index type, extra elements, polygons."""
    counts = ["uchar", "ushort", "uint", "int", "char"]
    indices = ["int", "uint", "ushort", "uchar", "short"]
    for k, (count, index) in enumerate(zip(counts, indices)):
        for quads in (False, True):
            path = tmp_path / f"m{k}{quads}.ply"
            faces = QUADS if quads else TRIANGLES
            path.write_bytes(_typed_file(order, vtype, count, index, faces))
            mesh = read_mesh(path)
            np.testing.assert_array_equal(mesh.V[:, :2], [[0, 0], [1, 0], [1, 1], [0, 1]])
            assert mesh.V[:, 2].tolist() == [0.25, -0.5, 1e300, -0.0]
            assert mesh.vertex_attributes["value"].tolist() == [0, 1, 100, 127]
            assert set(mesh.vertex_attributes) == {"value"}  # the list 'extra' is not a column
            want = [[0, 1, 2], [0, 2, 3], [0, 2, 3]] if quads else [[0, 1, 2], [0, 2, 3]]
            assert mesh.F.tolist() == want
            owner = [0, 0, 1] if quads else [0, 1]
            assert mesh.face_attributes["before"].tolist() == [5 + j for j in owner]
            assert mesh.face_attributes["after"].tolist() == [9 - j for j in owner]


def _round_trip_mesh(seed: int) -> Mesh:
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(6), np.arange(5))
    V = np.column_stack([x.ravel(), y.ravel(), rng.standard_normal(30)])
    i = np.arange(30).reshape(5, 6)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([b, d, c])])
    n, m = V.shape[0], F.shape[0]

    def every_dtype(count: int) -> dict:
        return {
            "f64": rng.standard_normal(count) * 1e-300,
            "f32": rng.standard_normal(count).astype(np.float32),
            "i8": rng.integers(-128, 128, count).astype(np.int8),
            "u16": rng.integers(0, 2**16, count).astype(np.uint16),
            "i32": rng.integers(-(2**31), 2**31, count).astype(np.int32),
            "i64_small": rng.integers(-(2**31), 2**31, count),
            "i64_big": rng.integers(2**40, 2**50, count),
            "u64": rng.integers(0, 2**31, count).astype(np.uint64),
            "flag": rng.random(count) < 0.5,
            "vec": rng.standard_normal((count, 3)),
            "nan_inf": np.where(rng.random(count) < 0.3, np.nan, -np.inf),
        }

    return Mesh(V, F).with_attributes(vertex=every_dtype(n), face=every_dtype(m))


@pytest.mark.parametrize("binary", [True, False])
def test_every_attribute_type_round_trips(tmp_path, binary):
    mesh = _round_trip_mesh(3)
    back = read_mesh(write_mesh(tmp_path / "m.ply", mesh, binary=binary))
    np.testing.assert_array_equal(back.V, mesh.V)
    np.testing.assert_array_equal(back.F, mesh.F)
    for got, sent in (
        (back.vertex_attributes, mesh.vertex_attributes),
        (back.face_attributes, mesh.face_attributes),
    ):
        want = {}
        for key, value in sent.items():
            if value.ndim == 2:
                want |= {f"{key}_{j}": value[:, j] for j in range(value.shape[1])}
            else:
                want[key] = value
        assert set(got) == set(want)
        for key, value in want.items():
            assert got[key].dtype == np.float64
            # f8 or exact integer storage, and %.17g in ASCII: every value comes back exactly
            np.testing.assert_array_equal(got[key], value.astype(np.float64), err_msg=key)


# --------------------------------------------------------------------------- bad files

HEAD = (
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
)
BODY = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
BAD = {
    # name: (content, start of the message after the path)
    "no_end_header": (
        HEAD.replace("end_header\n", "") + BODY,
        "has a malformed PLY header (line 9",
    ),
    "version": (HEAD.replace("1.0", "2.0") + BODY, "has a malformed PLY header (line 2: expected"),
    "format": (HEAD.replace("ascii", "utf8") + BODY, "has a malformed PLY header (line 2: unknown"),
    "type": (HEAD.replace("float x", "real x") + BODY, "has a malformed PLY header (line 4"),
    "count": (
        HEAD.replace("vertex 3", "vertex three") + BODY,
        "has a malformed PLY header (line 3",
    ),
    "negative": (
        HEAD.replace("vertex 3", "vertex -3") + BODY,
        "has a malformed PLY header (line 3",
    ),
    "no_format": (HEAD.replace("format ascii 1.0\n", "") + BODY, "has a malformed PLY header"),
    "prop_tokens": (HEAD.replace("float x", "float x y") + BODY, "has a malformed PLY header"),
    "header_cut": (HEAD[:-1], "has a malformed PLY header (line 9: early end-of-file"),
    "short_row": (HEAD + "0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "is truncated or has a row with too few"),
    "long_row": (
        HEAD + "0 0 0 7\n1 0 0\n0 1 0\n3 0 1 2\n",
        "has malformed PLY data (element 'vertex",
    ),
    "long_face": (HEAD + BODY.replace("3 0 1 2", "3 0 1 2 2"), "has malformed PLY data"),
    "no_rows": (HEAD, "is truncated: the data ends before"),
    "empty_element": (HEAD.replace("end_header", "element x 2\nend_header") + BODY, "is truncated"),
    "word": (HEAD + "0 0 0\n1 0 0x1\n0 1 0\n3 0 1 2\n", "has malformed PLY data (element 'vertex'"),
    "uchar_256": (HEAD + BODY.replace("3 0 1 2", "256 0 1 2"), "has malformed PLY data"),
    "non_ascii": (
        HEAD + BODY.replace("1 0 0", "1 0 \xe9"),
        "is declared ASCII PLY but contains non",
    ),
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_malformed_files_give_the_same_errors(tmp_path, name):
    content, start = BAD[name]
    path = tmp_path / f"{name}.ply"
    path.write_bytes(content.encode("latin-1"))
    with pytest.raises(MeshReadError) as info:
        read_mesh(path)
    assert str(info.value).startswith(f"{path}: {start}")


@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("quads", [False, True])
def test_binary_cut_anywhere_is_truncated(tmp_path, order, quads):
    """Cut at every byte of the data: always 'truncated', with the element and row."""
    data = _typed_file(order, "float", "uchar", "int", QUADS if quads else TRIANGLES)
    start = data.index(b"end_header\n") + len(b"end_header\n")
    for cut in range(start, len(data)):
        path = tmp_path / "cut.ply"
        path.write_bytes(data[:cut])
        with pytest.raises(MeshReadError, match=r"is truncated: .*\(element '\w+': row \d"):
            read_mesh(path)


@pytest.mark.parametrize("order", ["<", ">", ""])
def test_face_with_too_few_corners(tmp_path, order):
    path = tmp_path / "m.ply"
    path.write_bytes(_typed_file(order, "int", "uchar", "int", [[0, 1, 2], [], [2, 3]]))
    with pytest.raises(MeshReadError, match=r"2 faces have fewer than 3 .*first: face 1 with 0"):
        read_mesh(path)


@pytest.mark.parametrize("name", ["bone.ply", "colored_airplane.ply"])
def test_binary_block_reader_equals_row_reader(monkeypatch, name):
    """The one-call reading of fixed-size rows gives what the row-by-row reference gives."""
    fast = read_mesh(SAMPLES / name)
    with monkeypatch.context() as patch:
        patch.setattr(_ply_parse, "_fixed_layout", lambda *args: None)
        slow = read_mesh(SAMPLES / name)
    np.testing.assert_array_equal(fast.V, slow.V)
    np.testing.assert_array_equal(fast.F, slow.F)
    assert list(fast.vertex_attributes) == list(slow.vertex_attributes)
    for key, value in fast.vertex_attributes.items():
        np.testing.assert_array_equal(value, slow.vertex_attributes[key], err_msg=key)


@pytest.mark.parametrize("order", ["<", ">"])
def test_corrupt_list_count_is_truncated_without_allocating(tmp_path, order):
    """A face claiming 4,294,967,295 corners (16 GiB of indices) in a small file."""
    data = bytearray(_typed_file(order, "int", "uint", "int", TRIANGLES))
    count = data.index(b"end_header\n") + 11 + 4 * (4 + 4 + 8 + 4 + 1) + 6 * 4 + 4
    assert np.frombuffer(data, order + "u4", 1, count)[0] == 3  # the first face's corner count
    data[count : count + 4] = b"\xff" * 4
    path = tmp_path / "m.ply"
    path.write_bytes(bytes(data))
    with pytest.raises(MeshReadError, match=r"is truncated: .*'face': row 0: property 'vertex_in"):
        read_mesh(path)


def test_reading_and_writing_ply_never_imports_plyfile(tmp_path):
    """plyfile (GPL-3.0) is not a dependency: PLY works with its import blocked."""
    script = textwrap.dedent(
        f"""
        import sys
        class Block:
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] == "plyfile":
                    raise ImportError("plyfile is blocked")
        sys.meta_path.insert(0, Block())
        from igljoin.io import read_mesh, write_mesh
        for name in ("bone.ply", "colored_airplane.ply"):
            mesh = read_mesh({str(SAMPLES)!r} + "/" + name)
            for binary in (True, False):
                write_mesh({str(tmp_path)!r} + "/m.ply", mesh, binary=binary)
                assert read_mesh({str(tmp_path)!r} + "/m.ply").n_faces == mesh.n_faces
        print("plyfile" in sys.modules)
        """
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parent.parent)}
    proc = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=env
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "False"
