"""Tests of the validated mesh type (igljoin.mesh) and the surface checks (igljoin.validate)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import igljoin.mesh
from igljoin.errors import IgljoinError, MeshError
from igljoin.mesh import Mesh, as_mesh
from igljoin.validate import check_surface

# A unit right triangle and a unit square made of two triangles (both with normal +z).
TRI_V = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
TRI_F = [[0, 1, 2]]
SQ_V = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]
SQ_F = [[0, 1, 2], [0, 2, 3]]
CLEAN_FIX = "igljoin.clean"


# ----------------------------------------------------------------------------
# construction, dtypes, immutability
# ----------------------------------------------------------------------------


def test_mesh_error_is_a_value_error():
    assert issubclass(MeshError, IgljoinError)
    assert issubclass(MeshError, ValueError)


def test_dtypes_are_converted():
    V = np.array(SQ_V, dtype=np.float32)
    F = np.array(SQ_F, dtype=np.int32)
    m = Mesh(V, F)
    assert m.V.dtype == np.float64
    assert m.F.dtype == np.int64
    # float32 -> float64 widening is exact, so the values compare equal bit for bit
    np.testing.assert_array_equal(m.V, V.astype(np.float64))
    np.testing.assert_array_equal(m.F, F)
    assert (m.n_vertices, m.n_faces) == (4, 2)


def test_lists_are_accepted():
    m = Mesh(SQ_V, SQ_F)
    assert m.V.shape == (4, 3) and m.F.shape == (2, 3)
    assert m.V.dtype == np.float64 and m.F.dtype == np.int64


def test_integral_float_faces_are_accepted():
    m = Mesh(TRI_V, np.array([[0.0, 1.0, 2.0]]))
    assert m.F.dtype == np.int64
    np.testing.assert_array_equal(m.F, [[0, 1, 2]])


def test_arrays_are_read_only():
    m = Mesh(SQ_V, SQ_F, vertex_attributes={"w": np.arange(4.0)}, face_attributes={"q": [1, 2]})
    for a in (m.V, m.F, m.vertex_attributes["w"], m.face_attributes["q"]):
        assert not a.flags.writeable
        with pytest.raises(ValueError):
            a[0] = 7
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.V = np.zeros((4, 3))


def test_callers_writeable_arrays_untouched():
    V = np.array(SQ_V, dtype=np.float64)
    F = np.array(SQ_F, dtype=np.int64)
    w = np.arange(4.0)
    V0, F0, w0 = V.copy(), F.copy(), w.copy()
    m = Mesh(V, F, vertex_attributes={"w": w})
    # the caller's arrays keep their flags and contents ...
    assert V.flags.writeable and F.flags.writeable and w.flags.writeable
    np.testing.assert_array_equal(V, V0)
    np.testing.assert_array_equal(F, F0)
    np.testing.assert_array_equal(w, w0)
    # ... and editing them afterwards does not reach into the mesh
    assert not np.shares_memory(m.V, V)
    assert not np.shares_memory(m.F, F)
    assert not np.shares_memory(m.vertex_attributes["w"], w)
    V[0, 0] = 99.0
    F[0, 0] = 3
    w[0] = -1.0
    np.testing.assert_array_equal(m.V, V0)
    np.testing.assert_array_equal(m.F, F0)
    np.testing.assert_array_equal(m.vertex_attributes["w"], w0)


def test_callers_read_only_arrays_keep_their_flag():
    V = np.array(SQ_V, dtype=np.float64)
    F = np.array(SQ_F, dtype=np.int32)
    V.flags.writeable = False
    F.flags.writeable = False
    m = Mesh(V, F)
    assert not V.flags.writeable and not F.flags.writeable
    assert not m.V.flags.writeable and not m.F.flags.writeable
    np.testing.assert_array_equal(m.V, SQ_V)
    np.testing.assert_array_equal(m.F, SQ_F)


def test_mesh_does_not_alias_read_only_view_of_writeable_data():
    base = np.array(SQ_V, dtype=np.float64)
    view = base[:]
    view.flags.writeable = False
    m = Mesh(view, SQ_F)
    base[1, 0] = np.nan  # the caller edits its own (writeable) data afterwards
    assert np.isfinite(m.V).all()


def test_repr_and_counts():
    m = Mesh(TRI_V, TRI_F, name="leaflet")
    assert repr(m) == "Mesh(name='leaflet', n_vertices=3, n_faces=1)"


# ----------------------------------------------------------------------------
# as_mesh
# ----------------------------------------------------------------------------


def test_as_mesh_accepts_tuple_and_list_pairs():
    for pair in ((SQ_V, SQ_F), [SQ_V, SQ_F]):
        m = as_mesh(pair, name="guest")
        assert isinstance(m, Mesh)
        assert m.name == "guest"
        np.testing.assert_array_equal(m.F, SQ_F)


def test_as_mesh_returns_mesh_unchanged():
    m = Mesh(SQ_V, SQ_F)
    assert as_mesh(m) is m


@pytest.mark.parametrize("obj", [np.zeros((3, 3)), (SQ_V,), (SQ_V, SQ_F, None), "mesh.ply", None])
def test_as_mesh_rejects_other_objects(obj):
    with pytest.raises(MeshError, match=r"expected an igljoin\.Mesh or a \(V, F\) tuple"):
        as_mesh(obj, name="host")


def test_as_mesh_names_the_argument_in_errors():
    with pytest.raises(MeshError, match=r"^host: "):
        as_mesh((np.zeros((3, 2)), TRI_F), name="host")


# ----------------------------------------------------------------------------
# structural errors
# ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "V",
    [np.zeros((3, 2)), np.zeros((3, 4)), np.zeros(9), np.zeros((1, 3, 3)), []],
    ids=["n x 2", "n x 4", "flat", "3-d", "empty"],
)
def test_wrong_vertex_shape(V):
    with pytest.raises(MeshError, match=r"vertex array V has shape .*must be \(n, 3\)"):
        Mesh(V, TRI_F)


@pytest.mark.parametrize(
    "F",
    [[0, 1, 2], [[0, 1, 2, 0]], [[0, 1]], np.zeros((1, 3, 1), dtype=int)],
    ids=["flat", "quads", "edges", "3-d"],
)
def test_wrong_face_shape(F):
    with pytest.raises(MeshError, match=r"face array F has shape .*must be \(m, 3\)"):
        Mesh(TRI_V, F)


@pytest.mark.parametrize(
    "V",
    [[["a", "b", "c"]] * 3, [[0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]],
    ids=["strings", "ragged"],
)
def test_non_numeric_vertices(V):
    with pytest.raises(MeshError, match="cannot be converted to float64"):
        Mesh(V, TRI_F)


@pytest.mark.parametrize(
    "F",
    [[["0", "1", "2"]], [[True, False, True]], [[0, 1], [0, 1, 2]]],
    ids=["strings", "bool", "ragged"],
)
def test_non_numeric_faces(F):
    with pytest.raises(MeshError, match="face array F"):
        Mesh(TRI_V, F)


def test_non_finite_vertices_are_counted_and_named():
    V = np.array(SQ_V + [[2.0, 2.0, 0.0]])
    V[1, 0] = np.nan
    V[3, 2] = np.inf
    V[4, 1] = -np.inf
    with pytest.raises(MeshError) as info:
        Mesh(V, [[0, 1, 2], [0, 2, 3], [2, 4, 3]])
    msg = str(info.value)
    assert "3 vertices have NaN or infinite coordinates" in msg
    assert "[1, 3, 4]" in msg


@pytest.mark.parametrize("bad", [3, 10], ids=["one past", "far"])
def test_face_index_too_large(bad):
    with pytest.raises(MeshError) as info:
        Mesh(TRI_V, [[0, 1, bad]])
    msg = str(info.value)
    assert "every index must be in [0, 2]" in msg
    assert "3 vertices" in msg


def test_negative_face_index():
    with pytest.raises(MeshError, match=r"every index must be in \[0, 2\]"):
        Mesh(TRI_V, [[0, -1, 2]])


@pytest.mark.parametrize("F", [[], np.zeros((0, 3), dtype=np.int64)], ids=["list", "0 x 3"])
def test_empty_faces(F):
    with pytest.raises(MeshError, match="no faces"):
        Mesh(TRI_V, F)


@pytest.mark.parametrize("bad", [1.5, np.nan, np.inf], ids=["fraction", "nan", "inf"])
def test_float_faces_with_non_integer_values(bad):
    with pytest.raises(MeshError, match="must hold integer vertex indices"):
        Mesh(TRI_V, np.array([[0.0, 1.0, bad]]))


# ----------------------------------------------------------------------------
# attributes
# ----------------------------------------------------------------------------


def test_attributes_are_stored_read_only_copies():
    rgb = np.arange(12.0).reshape(4, 3)
    m = Mesh(SQ_V, SQ_F, vertex_attributes={"rgb": rgb}, face_attributes={"label": [3, 4]})
    np.testing.assert_array_equal(m.vertex_attributes["rgb"], rgb)
    np.testing.assert_array_equal(m.face_attributes["label"], [3, 4])
    assert rgb.flags.writeable


@pytest.mark.parametrize(
    ("kind", "attrs", "count"),
    [
        ("vertex", {"vertex_attributes": {"w": [1.0, 2.0, 3.0]}}, 4),
        ("vertex", {"vertex_attributes": {"w": 1.0}}, 4),
        ("face", {"face_attributes": {"q": [1, 2, 3]}}, 2),
    ],
    ids=["vertex short", "vertex scalar", "face long"],
)
def test_attribute_length_mismatch(kind, attrs, count):
    with pytest.raises(MeshError, match=rf"{kind} attribute .* one value per {kind} \({count}\)"):
        Mesh(SQ_V, SQ_F, **attrs)


def test_attribute_name_must_be_identifier():
    with pytest.raises(MeshError, match="not a plain identifier"):
        Mesh(SQ_V, SQ_F, vertex_attributes={"bad name": np.zeros(4)})


def test_attribute_name_must_be_a_string():
    with pytest.raises(MeshError):
        Mesh(SQ_V, SQ_F, vertex_attributes={3: np.zeros(4)})


def test_with_attributes_merges_and_overrides():
    m = Mesh(SQ_V, SQ_F, vertex_attributes={"a": np.zeros(4), "b": np.ones(4)}, name="wall")
    m2 = m.with_attributes(vertex={"b": np.full(4, 2.0), "c": np.arange(4)}, face={"f": [5, 6]})
    assert m2 is not m
    assert m2.name == "wall"
    assert set(m2.vertex_attributes) == {"a", "b", "c"}
    np.testing.assert_array_equal(m2.vertex_attributes["a"], 0.0)
    np.testing.assert_array_equal(m2.vertex_attributes["b"], 2.0)
    np.testing.assert_array_equal(m2.face_attributes["f"], [5, 6])
    np.testing.assert_array_equal(m2.V, m.V)
    np.testing.assert_array_equal(m2.F, m.F)
    # the original keeps its own attributes
    assert set(m.vertex_attributes) == {"a", "b"} and m.face_attributes == {}
    np.testing.assert_array_equal(m.vertex_attributes["b"], 1.0)


def test_with_attributes_validates():
    m = Mesh(SQ_V, SQ_F)
    with pytest.raises(MeshError, match="face attribute 'f'"):
        m.with_attributes(face={"f": [1, 2, 3]})


# ----------------------------------------------------------------------------
# size guard
# ----------------------------------------------------------------------------


def test_size_guard_on_vertices(monkeypatch):
    monkeypatch.setattr(igljoin.mesh, "MAX_ELEMENTS", 3)
    Mesh(TRI_V, TRI_F)  # exactly at the limit is fine
    with pytest.raises(MeshError, match="4 vertices exceed the size guard of 3") as info:
        Mesh(SQ_V, SQ_F)
    assert "igljoin.mesh.MAX_ELEMENTS" in str(info.value)


def test_size_guard_on_faces(monkeypatch):
    monkeypatch.setattr(igljoin.mesh, "MAX_ELEMENTS", 4)
    F = [[0, 1, 2], [0, 2, 3], [1, 2, 3], [0, 1, 3], [0, 1, 2]]
    with pytest.raises(MeshError, match="5 faces exceed the size guard of 4"):
        Mesh(SQ_V, F)


# ----------------------------------------------------------------------------
# check_surface
# ----------------------------------------------------------------------------


def _surface_error(V, F, role="guest") -> str:
    with pytest.raises(MeshError) as info:
        check_surface(Mesh(V, F), role)
    msg = str(info.value)
    assert msg.startswith(f"{role}: ")
    assert CLEAN_FIX in msg
    return msg


@pytest.mark.parametrize("role", ["host", "guest"])
def test_clean_surface_passes(role):
    check_surface(Mesh(SQ_V, SQ_F), role)


def test_face_repeating_a_vertex():
    msg = _surface_error(SQ_V, [[0, 1, 2], [0, 2, 2]])
    assert "1 faces repeat a vertex" in msg and "first [1]" in msg


def test_zero_area_face():
    # face 2 has three distinct but collinear vertices
    msg = _surface_error(SQ_V + [[2.0, 0.0, 0.0]], [[0, 1, 2], [0, 2, 3], [0, 1, 4]])
    assert "1 faces have zero area" in msg and "first [2]" in msg


@pytest.mark.parametrize("dup", [[2, 0, 1], [0, 2, 1]], ids=["rotated", "flipped"])
def test_duplicate_face(dup):
    msg = _surface_error(SQ_V, [[0, 1, 2], [0, 2, 3], dup])
    assert "1 faces are duplicated" in msg


def test_non_manifold_edge():
    # edge (0, 2) is shared by three faces: the square's two and a fin above it
    msg = _surface_error(SQ_V + [[0.5, 0.5, 1.0]], [[0, 1, 2], [0, 2, 3], [0, 2, 4]])
    assert "1 edges are shared by more than two faces" in msg
    assert "[[0, 2]]" in msg


def test_non_manifold_vertex():
    # two triangles (fans) touching only at vertex 0
    V = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]]
    msg = _surface_error(V, [[0, 1, 2], [0, 3, 4]])
    assert "1 vertices are non-manifold" in msg and "first [0]" in msg


def test_unreferenced_guest_vertex():
    # vertex 0 is used by no face
    msg = _surface_error([[5.0, 5.0, 5.0]] + SQ_V, [[1, 2, 3], [1, 3, 4]])
    assert "1 vertices are not used by any face" in msg and "first [0]" in msg


def test_unreferenced_host_vertex_is_allowed():
    check_surface(Mesh([[5.0, 5.0, 5.0]] + SQ_V, [[1, 2, 3], [1, 3, 4]]), "host")


def test_trailing_unreferenced_guest_vertex():
    # the last vertex is unused: libigl's per-vertex flags stop at the largest face index
    msg = _surface_error(SQ_V + [[5.0, 5.0, 5.0]], SQ_F)
    assert "1 vertices are not used by any face" in msg and "first [4]" in msg


def test_trailing_unreferenced_host_vertex_is_allowed():
    check_surface(Mesh(SQ_V + [[5.0, 5.0, 5.0]], SQ_F), "host")


def test_inconsistently_oriented_faces():
    # the second triangle is flipped: both faces traverse edge 2 -> 0
    msg = _surface_error(SQ_V, [[0, 1, 2], [0, 3, 2]])
    assert "inconsistently oriented" in msg


def test_guest_vertices_sharing_a_position():
    # two triangles glued along a seam whose vertices are duplicated, not shared
    V = SQ_V + [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0]]
    msg = _surface_error(V, [[0, 1, 2], [4, 5, 3]])
    assert "share their position" in msg
