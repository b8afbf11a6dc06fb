"""Tests of igljoin.io (mesh files) and igljoin.atomic (all-or-nothing output)."""

from __future__ import annotations

import errno
import hashlib
import os
from pathlib import Path

import numpy as np
import pytest

from igljoin.atomic import atomic_path, atomic_write_bytes, atomic_write_text
from igljoin.errors import MeshError, MeshReadError
from igljoin.io import read_mesh, write_mesh
from igljoin.mesh import Mesh

# --------------------------------------------------------------------------- fixtures


def _octahedron(seed: int = 0) -> Mesh:
    """A closed 6-vertex, 8-face mesh with irrational-looking coordinates.

    Random coordinates have full 53-bit mantissas, so any lossy text or
    float32 conversion in a writer shows up as a mismatch.
    """
    rng = np.random.default_rng(seed)
    base = np.array(
        [[0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], dtype=float
    )
    V = base + 0.1 * rng.standard_normal(base.shape)
    F = np.array(
        [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1], [5, 2, 1], [5, 3, 2], [5, 4, 3], [5, 1, 4]]
    )
    return Mesh(V, F, name="octahedron")


def _with_attributes(mesh: Mesh, seed: int = 1) -> Mesh:
    rng = np.random.default_rng(seed)
    n, m = mesh.n_vertices, mesh.n_faces
    return mesh.with_attributes(
        vertex={
            "quality": rng.standard_normal(n),
            "thickness": rng.random(n).astype(np.float32),
            "label": np.arange(n, dtype=np.int64) - 2,
            "fixed": np.arange(n) % 2 == 0,
            "normal": rng.standard_normal((n, 3)),
        },
        face={"quality": rng.random(m), "region": np.arange(m, dtype=np.uint16) * 7},
    )


def _write(path: Path, data: bytes | str) -> Path:
    if isinstance(data, str):
        data = data.encode("latin-1")
    path.write_bytes(data)
    return path


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _sample_dir() -> Path | None:
    try:
        import pymeshlab
    except ImportError:
        return None
    folder = Path(pymeshlab.__file__).parent / "tests" / "sample_meshes"
    return folder if folder.is_dir() else None


def _sample_files() -> list:
    folder = _sample_dir()
    if folder is None:
        return [pytest.param(None, marks=pytest.mark.skip(reason="pymeshlab not installed"))]
    files = sorted(p for p in folder.rglob("*") if p.suffix.lower() in (".obj", ".ply"))
    return [pytest.param(p, id=str(p.relative_to(folder))) for p in files]


TRIANGLE_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
TRIANGLE_OFF = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
ASCII_PLY_HEADER = (
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
)


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize(
    ("suffix", "binary"),
    [(".obj", True), (".off", True), (".ply", True), (".ply", False), (".stl", False)],
)
def test_round_trip_is_exact(tmp_path, suffix, binary):
    mesh = _octahedron()
    out = write_mesh(tmp_path / f"m{suffix}", mesh, binary=binary)
    assert out == tmp_path / f"m{suffix}"
    back = read_mesh(out)
    assert back.V.dtype == np.float64 and back.F.dtype == np.int64
    if suffix == ".stl":  # STL has no shared vertices: compare triangle corners in order
        np.testing.assert_array_equal(back.V[back.F], mesh.V[mesh.F])
        assert back.n_vertices == mesh.n_vertices  # identical corners were merged again
    else:
        np.testing.assert_array_equal(back.V, mesh.V)
        np.testing.assert_array_equal(back.F, mesh.F)


def test_binary_stl_round_trip_is_float32_exact_and_connected(tmp_path):
    mesh = _octahedron()
    back = read_mesh(write_mesh(tmp_path / "m.stl", mesh))
    # Binary STL stores float32: the corners must equal the float32-rounded input exactly.
    np.testing.assert_array_equal(back.V[back.F], mesh.V[mesh.F].astype(np.float32))
    assert back.n_vertices == 6 and back.n_faces == 8


@pytest.mark.parametrize("binary", [True, False])
def test_ply_attributes_round_trip(tmp_path, binary):
    mesh = _with_attributes(_octahedron())
    back = read_mesh(write_mesh(tmp_path / "m.ply", mesh, binary=binary))
    va, fa = mesh.vertex_attributes, mesh.face_attributes
    expected_vertex = {
        "quality": va["quality"],
        "thickness": va["thickness"].astype(np.float64),
        "label": va["label"].astype(np.float64),
        "fixed": va["fixed"].astype(np.float64),
        **{f"normal_{j}": va["normal"][:, j] for j in range(3)},
    }
    assert set(back.vertex_attributes) == set(expected_vertex)
    for key, value in expected_vertex.items():
        assert back.vertex_attributes[key].dtype == np.float64
        # Floats are stored as f8 and ints/bools exactly, so equality is exact.
        np.testing.assert_array_equal(back.vertex_attributes[key], value, err_msg=key)
    assert set(back.face_attributes) == {"quality", "region"}
    np.testing.assert_array_equal(back.face_attributes["quality"], fa["quality"])
    np.testing.assert_array_equal(back.face_attributes["region"], fa["region"])


def test_ply_property_types(tmp_path):
    mesh = _with_attributes(_octahedron())
    header = write_mesh(tmp_path / "m.ply", mesh).read_bytes().split(b"end_header")[0].decode()
    for line in (
        "property double x",
        "property double quality",
        "property double thickness",
        "property int label",
        "property uchar fixed",
        "property double normal_2",
        "property list uchar int vertex_indices",
        "property int region",
    ):
        assert line in header


def test_int_attribute_beyond_int32_is_kept_as_double(tmp_path):
    mesh = _octahedron().with_attributes(vertex={"big": np.full(6, 2**40, dtype=np.int64)})
    back = read_mesh(write_mesh(tmp_path / "m.ply", mesh))
    np.testing.assert_array_equal(back.vertex_attributes["big"], np.full(6, 2.0**40))


def test_uppercase_suffixes(tmp_path):
    mesh = _octahedron()
    for suffix in (".PLY", ".Obj", ".OFF", ".STL"):
        back = read_mesh(write_mesh(tmp_path / f"m{suffix}", mesh))
        assert back.n_faces == mesh.n_faces


def test_obj_and_off_drop_attributes_silently(tmp_path):
    mesh = _with_attributes(_octahedron())
    for suffix in (".obj", ".off", ".stl"):
        back = read_mesh(write_mesh(tmp_path / f"m{suffix}", mesh))
        assert back.vertex_attributes == {} and back.face_attributes == {}


def test_write_accepts_vf_tuple(tmp_path):
    mesh = _octahedron()
    back = read_mesh(write_mesh(tmp_path / "m.obj", (mesh.V, mesh.F)))
    np.testing.assert_array_equal(back.F, mesh.F)


def test_read_mesh_name(tmp_path):
    path = _write(tmp_path / "host.obj", TRIANGLE_OBJ)
    assert read_mesh(path).name == "host"
    assert read_mesh(path, name="guest").name == "guest"


# --------------------------------------------------------------------------- pymeshlab


@pytest.mark.parametrize("binary", [True, False])
def test_written_ply_opens_in_pymeshlab(tmp_path, binary):
    pymeshlab = pytest.importorskip("pymeshlab")
    mesh = _with_attributes(_octahedron())
    path = write_mesh(tmp_path / "m.ply", mesh, binary=binary)
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    loaded = ms.current_mesh()
    assert loaded.vertex_number() == mesh.n_vertices
    assert loaded.face_number() == mesh.n_faces
    # pymeshlab keeps double coordinates, and we write doubles: exact.
    np.testing.assert_array_equal(loaded.vertex_matrix(), mesh.V)
    np.testing.assert_array_equal(loaded.face_matrix(), mesh.F)
    # 'quality' is MeshLab's own scalar; it must be read as that, unchanged.
    np.testing.assert_array_equal(loaded.vertex_scalar_array(), mesh.vertex_attributes["quality"])
    np.testing.assert_array_equal(loaded.face_scalar_array(), mesh.face_attributes["quality"])


@pytest.mark.parametrize("suffix", [".obj", ".off", ".stl"])
def test_written_text_formats_open_in_pymeshlab(tmp_path, suffix):
    pymeshlab = pytest.importorskip("pymeshlab")
    mesh = _octahedron()
    path = write_mesh(tmp_path / f"m{suffix}", mesh)
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    assert ms.current_mesh().vertex_number() == mesh.n_vertices
    assert ms.current_mesh().face_number() == mesh.n_faces


@pytest.mark.parametrize("path", _sample_files())
def test_real_sample_meshes(path):
    """Every OBJ/PLY shipped with pymeshlab reads in-process, like pymeshlab reads it."""
    import pymeshlab

    before = _digest(path)
    mesh = read_mesh(path)
    assert mesh.n_vertices > 0 and mesh.n_faces > 0
    assert _digest(path) == before
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))  # pymeshlab reads every sample it ships
    reference = ms.current_mesh()
    assert mesh.n_vertices == reference.vertex_number()
    assert mesh.n_faces == reference.face_number()
    # pymeshlab holds doubles; files store float32 or float64, both exact in double.
    np.testing.assert_array_equal(mesh.V, reference.vertex_matrix())
    np.testing.assert_array_equal(mesh.F, reference.face_matrix())  # same faces, same order


def test_sample_ply_properties_become_attributes():
    folder = _sample_dir()
    if folder is None:
        pytest.skip("pymeshlab not installed")
    airplane = read_mesh(folder / "colored_airplane.ply")
    assert set(airplane.vertex_attributes) == {"red", "green", "blue", "alpha", "quality"}
    assert airplane.vertex_attributes["red"].shape == (airplane.n_vertices,)
    face = read_mesh(folder / "rangemaps" / "face000.ply")  # face element has flags, quality
    assert set(face.face_attributes) == {"flags", "quality"}
    assert face.face_attributes["quality"].shape == (face.n_faces,)


# --------------------------------------------------------------------------- parsing details


def test_obj_face_forms_negative_indices_and_polygons(tmp_path):
    text = (
        "# comment\nmtllib x.mtl\no thing\n"
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0 1.0\nvt 0 0\nvn 0 0 1\ng group\nusemtl m\ns 1\n"
        "f 1/1/1 2//1 3/1\n"  # mixed corner forms
        "f -4 -2 -1\n"  # relative indices: vertices 1, 3, 4
        "f 1 2 3 4\n"  # quad -> 2 triangles
        "l 1 2\n"
    )
    mesh = read_mesh(_write(tmp_path / "m.obj", text))
    assert mesh.F.tolist() == [[0, 1, 2], [0, 2, 3], [0, 1, 2], [0, 2, 3]]
    assert mesh.n_vertices == 4


def test_off_polygons_comments_and_color_variants(tmp_path):
    text = (
        "COFF\n# a comment\n5 2 0\n0 0 0 255 0 0 255\n1 0 0 1 1 1 1\n1 1 0 0 0 0 0\n"
        "0 1 0 0 0 0 0\n2 2 0 0 0 0 0\n4 0 1 2 3\n3 1 4 2  # trailing comment\n"
    )
    mesh = read_mesh(_write(tmp_path / "m.off", text))
    assert mesh.F.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 2]]


def test_off_counts_on_header_line(tmp_path):
    mesh = read_mesh(_write(tmp_path / "m.off", "OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"))
    assert mesh.n_faces == 1


def test_ascii_stl_merges_shared_corners(tmp_path):
    facet = "facet normal 0 0 1\nouter loop\n{}endloop\nendfacet\n"
    corners = [["0 0 0", "1 0 0", "0 1 0"], ["1 0 0", "1 1 0", "0 1 0"]]
    body = "".join(facet.format("".join(f"vertex {c}\n" for c in tri)) for tri in corners)
    mesh = read_mesh(_write(tmp_path / "m.stl", f"solid s\n{body}endsolid s\n"))
    assert mesh.n_vertices == 4
    assert mesh.F.tolist() == [[0, 1, 2], [1, 3, 2]]


def test_binary_stl_starting_with_solid(tmp_path):
    mesh = _octahedron()
    path = write_mesh(tmp_path / "m.stl", mesh)
    data = bytearray(path.read_bytes())
    data[:5] = b"solid"  # some exporters do this in binary files
    path.write_bytes(bytes(data))
    assert read_mesh(path).n_faces == 8


def test_ply_polygons_fan_triangulated_with_repeated_face_attributes(tmp_path):
    text = (
        "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
        "property float z\nproperty uchar red\nelement face 2\n"
        "property list uchar uint vertex_index\nproperty float weight\nend_header\n"
        "0 0 0 10\n1 0 0 20\n1 1 0 30\n0 1 0 40\n2 2 0 50\n4 0 1 2 3 0.5\n3 1 4 2 2.5\n"
    )
    mesh = read_mesh(_write(tmp_path / "m.ply", text))
    assert mesh.F.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 2]]
    np.testing.assert_array_equal(mesh.face_attributes["weight"], [0.5, 0.5, 2.5])
    np.testing.assert_array_equal(mesh.vertex_attributes["red"], [10, 20, 30, 40, 50])


def test_binary_ply_polygons(tmp_path):
    header = (
        b"ply\nformat binary_big_endian 1.0\nelement vertex 4\nproperty double x\n"
        b"property double y\nproperty double z\nelement face 1\n"
        b"property list uchar int vertex_indices\nend_header\n"
    )
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=">f8")
    face = np.array([4], dtype="u1").tobytes() + np.arange(4, dtype=">i4").tobytes()
    mesh = read_mesh(_write(tmp_path / "m.ply", header + V.tobytes() + face))
    assert mesh.F.tolist() == [[0, 1, 2], [0, 2, 3]]
    np.testing.assert_array_equal(mesh.V, V)


def test_reading_does_not_modify_inputs(tmp_path):
    mesh = _with_attributes(_octahedron())
    paths = [write_mesh(tmp_path / f"m{s}", mesh) for s in (".obj", ".off", ".ply", ".stl")]
    paths.append(write_mesh(tmp_path / "a.ply", mesh, binary=False))
    for path in paths:
        before = (_digest(path), path.stat().st_mtime_ns)
        read_mesh(path)
        assert (_digest(path), path.stat().st_mtime_ns) == before


def test_read_arrays_are_not_views_of_the_file(tmp_path):
    path = write_mesh(tmp_path / "m.ply", _with_attributes(_octahedron()))
    mesh = read_mesh(path)
    expected = mesh.V.copy()
    path.write_bytes(b"overwritten")  # a memory map would now see garbage (or crash)
    np.testing.assert_array_equal(mesh.V, expected)


# --------------------------------------------------------------------------- bad inputs

_NOISE = np.random.default_rng(42).bytes(4000)


def _cut(data: bytes, fraction: float = 0.5) -> bytes:
    return data[: int(len(data) * fraction)]


def _ply_text(vertex_lines: str, face_lines: str, n_faces: int = 1) -> str:
    return ASCII_PLY_HEADER.replace("face 1", f"face {n_faces}") + vertex_lines + face_lines


BAD_FILES = {
    # name: (content, expected substring of the message)
    "empty.obj": (b"", "is empty"),
    "empty.ply": (b"", "is empty"),
    "noise.obj": (_NOISE, "binary data"),
    "noise.off": (_NOISE, "binary data"),
    "noise.ply": (_NOISE, "'ply' magic"),
    "noise.stl": (_NOISE, "truncated or not an STL"),
    "tiny.stl": (_NOISE[:50], "too short"),
    "text.obj": ("hello\nworld\n", "no OBJ vertex"),
    "text.off": ("hello\nworld\n", "'OFF' keyword"),
    "text.ply": ("ply\nhello world\n", "malformed PLY header"),
    "novertex.obj": ("f 1 2 3\n", "defines only 0 vertices"),
    "missing_vertex.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", "references vertex 7"),
    "zero_index.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "start at 1"),
    "relative.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n", "before the first vertex"),
    "line.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "needs at least 3"),
    "word.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf a b c\n", "not a vertex index"),
    "badnum.obj": ("v 0 0 x\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "not numbers"),
    "short_vertex.obj": ("v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "needs 3"),
    "huge_index.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n", "far beyond"),
    "points.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "has no faces"),
    "points.off": ("OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n", "has no faces"),
    "truncated.off": ("OFF\n4 2 0\n0 0 0\n1 0 0\n", "truncated"),
    "header_only.off": ("OFF\n", "truncated"),
    "bad_counts.off": ("OFF\nthree one zero\n", "expected vertex and face counts"),
    "negative.off": ("OFF\n-3 1 0\n0 0 0\n", "negative counts"),
    "bad_polygon.off": ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n99 0 1 2\n", "declares 99 vertices"),
    "binary.off": ("OFF BINARY\n3 1 0\n", "binary OFF"),
    "4d.off": ("4OFF\n3 1 0\n", "'OFF' keyword"),
    "bad_vertex.off": ("OFF\n3 1 0\n0 0 x\n1 0 0\n0 1 0\n3 0 1 2\n", "is not three numbers"),
    "truncated_ascii.stl": (
        "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n",
        "truncated",
    ),
    "quad.stl": (
        "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 1 1 0\n"
        "vertex 0 1 0\nendloop\nendfacet\nendsolid s\n",
        "STL facets are triangles",
    ),
    "zero.stl": (b"\0" * 80 + b"\0\0\0\0", "has no vertices"),
    "no_faces.ply": (
        ASCII_PLY_HEADER.split("element face")[0] + "end_header\n0 0 0\n1 0 0\n0 1 0\n",
        "has no faces",
    ),
    "zero_faces.ply": (_ply_text("0 0 0\n1 0 0\n0 1 0\n", "", n_faces=0), "has no faces"),
    "segment.ply": (_ply_text("0 0 0\n1 0 0\n0 1 0\n", "2 0 1\n"), "fewer than 3 vertices"),
    "bad_number.ply": (_ply_text("0 0 0\n1 0 x\n0 1 0\n", "3 0 1 2\n"), "malformed PLY data"),
    "non_ascii.ply": (_ply_text("0 0 0\n1 0 \xe9\n0 1 0\n", "3 0 1 2\n"), "non-ASCII"),
    "huge_count.ply": (
        ASCII_PLY_HEADER.replace("vertex 3", "vertex 99999999999") + "0 0 0\n",
        "header declares 99999999999 'vertex' rows",
    ),
    "no_vertex.ply": (
        "ply\nformat ascii 1.0\nelement face 0\n"
        "property list uchar int vertex_indices\nend_header\n",
        "no 'vertex'",
    ),
    "no_z.ply": (
        ASCII_PLY_HEADER.replace("property float z\n", "") + "0 0\n1 0\n0 1\n3 0 1 2\n",
        "lacks the coordinate",
    ),
    "no_index_list.ply": (
        ASCII_PLY_HEADER.replace("vertex_indices", "corners") + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
        "no 'vertex_indices'",
    ),
    "index_out_of_range.ply": (
        _ply_text("0 0 0\n1 0 0\n0 1 0\n", "3 0 1 5\n"),
        "face indices range over [0, 5]",
    ),
    "nan.off": ("OFF\n3 1 0\n0 0 nan\n1 0 0\n0 1 0\n3 0 1 2\n", "NaN"),
    "nan.obj": ("v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
    "inf.ply": (_ply_text("0 0 inf\n1 0 0\n0 1 0\n", "3 0 1 2\n"), "NaN or infinite"),
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_bad_file_raises_clear_mesh_read_error(tmp_path, name):
    content, expected = BAD_FILES[name]
    path = _write(tmp_path / name, content)
    before = _digest(path)
    with pytest.raises(MeshReadError) as info:
        read_mesh(path)
    message = str(info.value)
    assert expected in message
    assert str(path) in message
    assert isinstance(info.value, ValueError) and isinstance(info.value, MeshError)
    assert _digest(path) == before


@pytest.mark.parametrize("binary", [True, False])
@pytest.mark.parametrize("fraction", [0.3, 0.6, 0.95])
def test_truncated_ply_is_reported_as_truncated(tmp_path, binary, fraction):
    source = write_mesh(tmp_path / "full.ply", _with_attributes(_octahedron()), binary=binary)
    data = source.read_bytes()
    header_end = data.index(b"end_header\n") + len(b"end_header\n")
    cut = header_end + int((len(data) - header_end) * fraction)
    path = _write(tmp_path / "cut.ply", data[:cut])
    with pytest.raises(MeshReadError, match="truncated"):
        read_mesh(path)


@pytest.mark.parametrize("suffix", [".obj", ".off", ".stl"])
@pytest.mark.parametrize("binary", [True, False])
def test_truncated_other_formats_fail_cleanly(tmp_path, suffix, binary):
    source = write_mesh(tmp_path / f"full{suffix}", _octahedron(), binary=binary)
    data = source.read_bytes()
    # Cut inside the last record: the file must be rejected, never read as a smaller mesh
    # and never crash. (A text file cut exactly between records can't be detected.)
    path = _write(tmp_path / f"cut{suffix}", data[: len(data) - 12])
    with pytest.raises(MeshReadError):
        read_mesh(path)


@pytest.mark.parametrize("suffix", [".obj", ".off", ".ply", ".stl"])
@pytest.mark.parametrize("seed", range(5))
def test_binary_noise_never_crashes(tmp_path, suffix, seed):
    data = np.random.default_rng(seed).bytes(10 + 997 * seed)
    path = _write(tmp_path / f"noise{suffix}", data)
    with pytest.raises(MeshReadError):
        read_mesh(path)


@pytest.mark.parametrize("suffix", [".ply", ".stl"])
def test_corrupted_binary_payload_never_crashes(tmp_path, suffix):
    """Random bytes after a valid header: a clear error or some mesh, never a crash."""
    source = write_mesh(tmp_path / f"full{suffix}", _octahedron())
    data = bytearray(source.read_bytes())
    start = data.index(b"end_header\n") + 11 if suffix == ".ply" else 84
    rng = np.random.default_rng(7)
    data[start:] = rng.bytes(len(data) - start)
    path = _write(tmp_path / f"bad{suffix}", bytes(data))
    try:
        read_mesh(path)
    except MeshReadError as exc:
        assert str(path) in str(exc)


def test_missing_file(tmp_path):
    path = tmp_path / "nope.ply"
    with pytest.raises(FileNotFoundError, match="mesh file not found") as info:
        read_mesh(path)
    assert str(path) in str(info.value)


def test_directory(tmp_path):
    path = tmp_path / "folder.obj"
    path.mkdir()
    with pytest.raises(MeshReadError, match="is a directory"):
        read_mesh(path)


@pytest.mark.parametrize("name", ["mesh.xyz", "mesh", "mesh.ply.gz"])
def test_unknown_suffix_lists_supported_ones(tmp_path, name):
    path = _write(tmp_path / name, TRIANGLE_OBJ)
    with pytest.raises(MeshReadError, match=r"\.obj, \.off, \.ply, \.stl") as info:
        read_mesh(path)
    assert "not a supported mesh format" in str(info.value)


# --------------------------------------------------------------------------- writing errors


def test_write_unknown_suffix(tmp_path):
    with pytest.raises(MeshError, match=r"unsupported suffix '\.xyz'"):
        write_mesh(tmp_path / "m.xyz", _octahedron())
    assert list(tmp_path.iterdir()) == []


def test_write_missing_directory(tmp_path):
    missing = tmp_path / "no" / "such"
    with pytest.raises(FileNotFoundError, match="does not exist") as info:
        write_mesh(missing / "m.ply", _octahedron())
    assert str(missing) in str(info.value)
    assert not missing.exists()


def test_write_unstorable_attribute_leaves_old_file(tmp_path):
    path = _write(tmp_path / "m.ply", b"old contents")
    mesh = _octahedron().with_attributes(vertex={"z2": np.ones(6, dtype=complex)})
    with pytest.raises(MeshError, match="PLY cannot store"):
        write_mesh(path, mesh)
    assert path.read_bytes() == b"old contents"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.ply"]


def test_write_attribute_name_clash(tmp_path):
    mesh = _octahedron().with_attributes(vertex={"n": np.zeros((6, 2)), "n_1": np.zeros(6)})
    with pytest.raises(MeshError, match="already used"):
        write_mesh(tmp_path / "m.ply", mesh)
    with pytest.raises(MeshError, match="already used"):
        write_mesh(tmp_path / "m.ply", _octahedron().with_attributes(vertex={"x": np.zeros(6)}))


def test_write_replaces_existing_file(tmp_path):
    path = _write(tmp_path / "m.obj", b"old")
    write_mesh(path, _octahedron())
    assert read_mesh(path).n_faces == 8
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.obj"]


# --------------------------------------------------------------------------- atomic output


def test_atomic_path_temp_name_and_success(tmp_path):
    target = tmp_path / "out.ply"
    with atomic_path(target) as tmp:
        assert tmp.parent == tmp_path
        assert tmp.name.startswith(".out.tmp-") and tmp.suffix == ".ply"
        assert tmp.exists() and not target.exists()
        tmp.write_bytes(b"new")
    assert target.read_bytes() == b"new"
    assert not tmp.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.ply"]


def test_atomic_path_failure_midway_keeps_old_file(tmp_path):
    target = _write(tmp_path / "out.txt", b"old contents")
    with pytest.raises(RuntimeError, match="writer broke"):
        with atomic_path(target) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(b"half of the new")
            raise RuntimeError("writer broke")
    assert target.read_bytes() == b"old contents"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


def test_atomic_path_failure_without_old_file_leaves_nothing(tmp_path):
    with pytest.raises(KeyError):
        with atomic_path(tmp_path / "new.bin") as tmp:
            tmp.write_bytes(b"partial")
            raise KeyError("boom")
    assert list(tmp_path.iterdir()) == []


def test_atomic_path_disk_full_inside_writer(tmp_path):
    target = _write(tmp_path / "out.stl", b"old contents")
    with pytest.raises(OSError) as info:
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"partial")
            raise OSError(errno.ENOSPC, "No space left on device")
    message = str(info.value)
    assert info.value.errno == errno.ENOSPC
    assert "disk is full" in message and str(target) in message
    assert "no partial file was left" in message
    assert target.read_bytes() == b"old contents"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.stl"]


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EDQUOT])
def test_write_mesh_disk_full_on_replace(tmp_path, monkeypatch, code):
    # A real full disk needs a root-mounted tiny file system; simulate the failing rename.
    target = _write(tmp_path / "m.ply", b"old contents")

    def full(src, dst):
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(os, "replace", full)
    with pytest.raises(OSError, match="disk is full") as info:
        write_mesh(target, _octahedron())
    assert str(target) in str(info.value) and "no partial file was left" in str(info.value)
    assert target.read_bytes() == b"old contents"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.ply"]


def test_other_os_errors_pass_through(tmp_path):
    with pytest.raises(PermissionError, match="denied"):
        with atomic_path(tmp_path / "x.txt"):
            raise PermissionError(errno.EACCES, "denied")
    assert list(tmp_path.iterdir()) == []


def test_atomic_path_missing_parent(tmp_path):
    missing = tmp_path / "absent"
    with pytest.raises(FileNotFoundError) as info:
        with atomic_path(missing / "x.txt"):
            pytest.fail("must not be reached")
    assert str(missing) in str(info.value) and "does not exist" in str(info.value)
    assert not missing.exists()


def test_atomic_path_target_is_directory(tmp_path):
    (tmp_path / "d.ply").mkdir()
    with pytest.raises(IsADirectoryError, match="is an existing directory"):
        with atomic_path(tmp_path / "d.ply"):
            pytest.fail("must not be reached")


def test_atomic_write_helpers(tmp_path):
    text_path = atomic_write_text(tmp_path / "a.txt", "héllo\r\nworld\n")
    assert text_path == tmp_path / "a.txt"
    assert text_path.read_bytes() == "héllo\r\nworld\n".encode()
    bytes_path = atomic_write_bytes(tmp_path / "b.bin", b"\0\1\2")
    assert bytes_path.read_bytes() == b"\0\1\2"
    atomic_write_bytes(bytes_path, b"new")
    assert bytes_path.read_bytes() == b"new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.bin"]


def test_atomic_path_keeps_permissions_of_existing_file(tmp_path):
    target = _write(tmp_path / "m.txt", b"old")
    target.chmod(0o640)
    atomic_write_text(target, "new")
    assert target.stat().st_mode & 0o777 == 0o640


@pytest.mark.parametrize("n_corners", [3, 4])
def test_ply_float_face_indices_are_rejected(tmp_path, n_corners):
    header = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\n"
        b"property float y\nproperty float z\nelement face 1\n"
        b"property list uchar float vertex_indices\nend_header\n"
    )
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype="<f4")
    face = bytes([n_corners]) + np.arange(n_corners, dtype="<f4").tobytes()
    path = _write(tmp_path / "m.ply", header + V.tobytes() + face)
    with pytest.raises(MeshReadError, match="not integers"):
        read_mesh(path)


def test_text_formats_accept_crlf_and_latin1_comments(tmp_path):
    obj = "# cr\xe9\xe9 \x85 f 9 9 9\r\nv 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 2 3\r\n"
    assert read_mesh(_write(tmp_path / "m.obj", obj)).F.tolist() == [[0, 1, 2]]
    off = TRIANGLE_OFF.replace("\n", "\r\n")
    assert read_mesh(_write(tmp_path / "m.off", off)).F.tolist() == [[0, 1, 2]]
