"""``igljoin clean cow.obj``: the real sample mesh is repaired so that the join accepts it."""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest

import igljoin
from igljoin.clean import TOUCH_SEPARATION, diagnose
from igljoin.cli import main

from .cuts import cut_piece, sample_mesh_dir

COW = sample_mesh_dir() / "cow.obj"


@pytest.fixture(scope="module")
def cleaned(tmp_path_factory) -> tuple[igljoin.Mesh, int, str]:
    out = tmp_path_factory.mktemp("cow") / "cow-clean.ply"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):  # the command itself, in-process: main(argv)
        code = main(["clean", str(COW), "-o", str(out)])
    return igljoin.read_mesh(out), code, buf.getvalue()


def test_clean_repairs_the_real_cow(cleaned):
    mesh, code, stdout = cleaned
    raw = igljoin.read_mesh(COW)
    assert diagnose(raw)["problems"]["duplicate_vertices"] == 1  # the touching point
    assert code == 0
    assert "touching vertices separated: 1" in stdout
    assert not any(diagnose(mesh)["problems"].values())
    assert (mesh.n_vertices, mesh.n_faces) == (raw.n_vertices, raw.n_faces)
    # only the separated copy moved, and by TOUCH_SEPARATION mean edges (to rounding, 1e-9)
    edges = np.linalg.norm(raw.V[raw.F[:, [1, 2, 0]]] - raw.V[raw.F], axis=2)
    step = np.linalg.norm(mesh.V - raw.V, axis=1)
    assert int((step > 0).sum()) == 1
    assert step.max() == pytest.approx(TOUCH_SEPARATION * edges.mean(), rel=1e-9)


def test_the_join_accepts_the_cleaned_cow(cleaned):
    mesh = cleaned[0]
    raw = igljoin.read_mesh(COW)
    moved = int(np.argmax(np.linalg.norm(mesh.V - raw.V, axis=1)))
    far = int(np.argmax(np.linalg.norm(raw.V - raw.V[moved], axis=1)))  # cut away from it
    results = {}
    for name, source in (("raw", raw), ("clean", mesh)):
        cut = cut_piece(source, far, 0.25)
        assert cut is not None
        guest = cut.host  # the cow with an opening: holds the touching point
        try:
            res = igljoin.join(cut.piece, guest, None, None)
            results[name] = res.converged
        except igljoin.MeshError as exc:
            results[name] = str(exc)
    assert "share their position" in results["raw"]  # the problem clean repairs
    assert results["clean"] is True
