"""The vectorised OBJ/OFF/STL/PLY readers give exactly what the reference parsers give.

Each text reader parses plain blocks with numpy and hands any other block to
its record-by-record reference parser. These tests generate seeded variants
of real and synthetic meshes, well-formed and broken, and check both paths
return the same arrays, or raise the same MeshReadError message.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from igljoin.errors import MeshReadError
from igljoin.io import _common, obj, off, ply, read_mesh, stl, write_mesh
from igljoin.mesh import Mesh

SAMPLES = Path(__import__("pymeshlab").__file__).parent / "tests" / "sample_meshes"


def _outcome(path: Path):
    try:
        m = read_mesh(path)
    except MeshReadError as exc:
        return ("error", str(exc))
    return ("mesh", m.V.tobytes(), m.F.tobytes(), sorted(m.vertex_attributes))


def _fast_blocks(path: Path, module, monkeypatch) -> int:
    """How many blocks of ``path`` the vectorised path parsed (the rest went to the reference)."""
    done = []
    original = module._fast
    with monkeypatch.context() as patch:
        patch.setattr(module, "_fast", lambda *args: done.append(original(*args)) or done[-1])
        _outcome(path)
    return sum(done)


def _reference(path: Path, module, monkeypatch):
    with monkeypatch.context() as patch:
        patch.setattr(module, "_fast", lambda *args: False)
        return _outcome(path)


def _grid(n: int, seed: int) -> Mesh:
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(n), np.arange(n))
    V = np.column_stack([x.ravel(), y.ravel(), rng.standard_normal(n * n)]).astype(float)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([b, d, c])])
    return Mesh(V + 0.1 * rng.standard_normal(V.shape), F)


def _obj_text(mesh: Mesh, rng, style: str) -> str:
    V, F = mesh.V.tolist(), mesh.F.tolist()
    if style == "plain":
        lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in V] + [
            f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F
        ]
    elif style == "slashes":
        lines = [f"v {x:.9g} {y:.9g} {z:.9g}\nvt 0.5 0.5\nvn 0 0 1" for x, y, z in V]
        lines += ["g part", "usemtl skin", "s 1"]
        lines += [f"f {a + 1}/{a + 1}/{a + 1} {b + 1}//{b + 1} {c + 1}/{c + 1}" for a, b, c in F]
    elif style == "relative":  # faces right after their vertices, with negative indices
        lines = [f"v {x!r} {y!r} {z!r} 0.5 0.25 1" for x, y, z in V]
        n = len(V)
        lines += [f"f {a - n} {b - n} {c - n}" for a, b, c in F]
    elif style == "quads":
        lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in V]
        lines += [f"f {a + 1} {b + 1} {c + 1} {c + 1}" for a, b, c in F[::2]]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F[1::2]]
    else:  # "messy": comments, indentation, tabs, blank lines, CRLF, continuations
        lines = [
            f"v\t{x!r} {y!r} {z!r}"
            if k % 7 == 0
            else f"v {x!r} {y!r} {z!r}  # c"
            if k % 5 == 0
            else f"v {x!r} {y!r} {z!r}"
            for k, (x, y, z) in enumerate(V)
        ]
        lines.insert(3, "")
        lines += [
            f"  f {a + 1} {b + 1} \\\n {c + 1}" if k % 11 == 0 else f"f {a + 1} {b + 1} {c + 1}"
            for k, (a, b, c) in enumerate(F)
        ]
        return "\r\n".join(lines) + "\r\n"
    return "\n".join(lines) + "\n"


def _break(text: str, rng) -> str:
    """Corrupt one random record of ``text`` in one of several ways."""
    lines = text.split("\n")
    k = int(rng.integers(len(lines) - 1))
    tokens = lines[k].split(" ")
    j = int(rng.integers(len(tokens)))
    how = int(rng.integers(7))
    if how == 0:
        tokens[j] = "x1"
    elif how == 1:
        tokens = tokens[:2]
    elif how == 2:
        tokens[j] = "0"
    elif how == 3:
        tokens[j] = str(10**19)
    elif how == 4:
        tokens[j] = "-99999"
    elif how == 5:
        tokens[j] = "1e"
    else:
        tokens[j] = "/" + tokens[j]
    lines[k] = " ".join(tokens)
    return "\n".join(lines)


@pytest.mark.parametrize("style", ["plain", "slashes", "relative", "quads", "messy"])
def test_obj_fast_equals_reference(tmp_path, monkeypatch, style):
    monkeypatch.setattr(_common, "CHUNK_BYTES", 2048)  # many blocks: carried state is tested
    rng = np.random.default_rng(7)
    path = tmp_path / "m.obj"
    path.write_bytes(_obj_text(_grid(9, 1), rng, style).encode())
    good = _outcome(path)
    assert good[0] == "mesh" and good == _reference(path, obj, monkeypatch)
    assert (_fast_blocks(path, obj, monkeypatch) > 0) == (style != "messy")
    kinds = set()
    for trial in range(12):
        path.write_bytes(_break(_obj_text(_grid(6, trial), rng, style), rng).encode())
        got = _outcome(path)
        assert got == _reference(path, obj, monkeypatch), (style, trial)
        kinds.add(got[0])
    assert "error" in kinds  # the corruptions are caught, identically


def _off_text(mesh: Mesh, style: str) -> str:
    V, F = mesh.V.tolist(), mesh.F.tolist()
    head = f"OFF\n{len(V)} {len(F)} 0\n"
    if style == "colours":
        head = f"COFF {len(V)} {len(F)} 0\n"
        rows = [f"{x!r} {y!r} {z!r} 255 0 0 255" for x, y, z in V]
        rows += [f"3 {a} {b} {c} 0.5 0.5 0.5" for a, b, c in F]
    elif style == "polygons":
        rows = [f"{x!r}\t{y!r} {z!r}" for x, y, z in V]
        rows += [
            f"4 {a} {b} {c} {c}" if k % 3 else f"3 {a} {b} {c}" for k, (a, b, c) in enumerate(F)
        ]
    else:
        rows = [f"{x!r} {y!r} {z!r}" for x, y, z in V] + [f"3 {a} {b} {c}" for a, b, c in F]
        rows.insert(2, "# a comment")
    return head + "\n".join(rows) + "\n"


@pytest.mark.parametrize("style", ["plain", "colours", "polygons"])
def test_off_fast_equals_reference(tmp_path, monkeypatch, style):
    monkeypatch.setattr(_common, "CHUNK_BYTES", 2048)
    rng = np.random.default_rng(3)
    path = tmp_path / "m.off"
    path.write_text(_off_text(_grid(9, 2), style))
    good = _outcome(path)
    assert good[0] == "mesh" and good == _reference(path, off, monkeypatch)
    assert _fast_blocks(path, off, monkeypatch) > 0
    kinds = set()
    for trial in range(12):
        path.write_text(_break(_off_text(_grid(6, trial), style), rng))
        got = _outcome(path)
        assert got == _reference(path, off, monkeypatch), (style, trial)
        kinds.add(got[0])
    assert "error" in kinds


def test_stl_fast_equals_reference(tmp_path, monkeypatch):
    monkeypatch.setattr(_common, "CHUNK_BYTES", 4096)
    rng = np.random.default_rng(5)
    path = write_mesh(tmp_path / "m.stl", _grid(9, 3), binary=False)
    good = _outcome(path)
    assert good[0] == "mesh" and good == _reference(path, stl, monkeypatch)
    assert _fast_blocks(path, stl, monkeypatch) > 1
    text = path.read_text()
    kinds = set()
    for trial in range(12):
        path.write_text(_break(text, rng))
        got = _outcome(path)
        assert got == _reference(path, stl, monkeypatch), trial
        kinds.add(got[0])
    assert "error" in kinds


def test_ascii_ply_fast_equals_row_reader(tmp_path, monkeypatch):
    rng = np.random.default_rng(11)
    mesh = _grid(8, 4)
    mesh = mesh.with_attributes(
        vertex={"q": rng.standard_normal(mesh.n_vertices), "label": np.arange(mesh.n_vertices)},
        face={"area_ratio": rng.random(mesh.n_faces), "fixed": np.arange(mesh.n_faces) % 2 == 0},
    )
    path = write_mesh(tmp_path / "m.ply", mesh)  # face attributes: ASCII
    assert path.read_bytes().startswith(b"ply\nformat ascii 1.0\n")
    fast = read_mesh(path)
    with monkeypatch.context() as patch:
        patch.setattr(ply, "_read_ascii_fast", lambda path: None)
        slow = read_mesh(path)
    for a, b in ((fast.V, slow.V), (fast.F, slow.F), (fast.V, mesh.V), (fast.F, mesh.F)):
        np.testing.assert_array_equal(a, b)
    for kind in ("vertex_attributes", "face_attributes"):
        got, want = getattr(fast, kind), getattr(slow, kind)
        assert list(got) == list(want)
        for name in got:
            assert got[name].dtype == want[name].dtype == np.float64
            np.testing.assert_array_equal(got[name], want[name])


@pytest.mark.parametrize("name", ["bunny10k_textured.obj", "cow.obj", "airplane.obj"])
def test_real_meshes_in_every_text_format(tmp_path, monkeypatch, name):
    """Sample OBJ files (vt/vn, groups, slashes) and igljoin's own OFF/STL writes of them."""
    source = SAMPLES / name
    assert _outcome(source) == _reference(source, obj, monkeypatch)
    mesh = read_mesh(source)
    for suffix, module in ((".off", off), (".stl", stl)):
        path = write_mesh(tmp_path / f"m{suffix}", mesh, binary=False)
        assert _outcome(path) == _reference(path, module, monkeypatch), (name, suffix)
        back = read_mesh(path)
        if suffix == ".off":
            np.testing.assert_array_equal(back.V, mesh.V)
            np.testing.assert_array_equal(back.F, mesh.F)


def test_merge_vertices_equals_numpy_unique(monkeypatch):
    rng = np.random.default_rng(0)
    pool = np.vstack([rng.random((50, 3)), [[0.0, 0.0, 0.0], [-0.0, 0.0, -0.0]]])
    P = pool[rng.integers(0, pool.shape[0], size=3 * 400)]

    def by_unique(P):
        uniq, first, inverse = np.unique(P, axis=0, return_index=True, return_inverse=True)
        order = np.argsort(first, kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        return uniq[order], rank[inverse.reshape(-1)].reshape(-1, 3)

    want_V, want_F = by_unique(P)
    for dtype in (np.float64, np.float32):
        V, F = _common.merge_vertices(P.astype(dtype))
        exp_V, exp_F = by_unique(P.astype(dtype))
        np.testing.assert_array_equal(V, exp_V.astype(np.float64))
        np.testing.assert_array_equal(F, exp_F)
    # every position colliding in the hash: the exact fallback gives the same answer
    monkeypatch.setattr(_common, "_mix", lambda x: np.zeros_like(x))
    V, F = _common.merge_vertices(P)
    np.testing.assert_array_equal(V, want_V)
    np.testing.assert_array_equal(F, want_F)


@pytest.mark.parametrize("keep", [0, 1, 2, 3])
def test_ascii_ply_with_missing_rows_is_truncated(tmp_path, keep):
    """Fewer rows than the header declares go to the row-by-row reader, which reports it."""
    rows = ["0 0 0", "1 0 0", "0 1 0", "3 0 1 2"][:keep]
    header = (
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    path = tmp_path / "cut.ply"
    path.write_text(header + "".join(r + "\n" for r in rows))
    with pytest.raises(MeshReadError, match="is truncated"):
        read_mesh(path)
