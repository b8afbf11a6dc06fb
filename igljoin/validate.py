"""Topological checks a mesh must pass before it is joined."""

from __future__ import annotations

import igl
import numpy as np

from .errors import MeshError, SolveError
from .mesh import Mesh

__all__ = ["check_surface", "check_guest_reaches_seam", "relative_area_floor"]

#: Faces whose area is below this fraction of the mean face area count as zero-area.
relative_area_floor = 1e-12


def _first(idx: np.ndarray, k: int = 5) -> str:
    return str(np.asarray(idx)[:k].tolist())


def check_surface(mesh: Mesh, role: str) -> None:
    """Raise :class:`MeshError` unless ``mesh`` is a clean manifold triangle surface.

    Checks faces repeating a vertex, zero-area faces, duplicate faces,
    non-manifold edges and vertices and (for the guest) unreferenced vertices.

    Parameters
    ----------
    mesh : Mesh
    role : {"host", "guest"}
    """
    F = mesh.F
    fix = "repair it with igljoin.clean(mesh) (or `igljoin clean IN -o OUT`)"
    rep = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    if rep.any():
        idx = np.flatnonzero(rep)
        raise MeshError(
            f"{role}: {idx.size} faces repeat a vertex (degenerate; first {_first(idx)}); {fix}"
        )
    area = igl.doublearea(mesh.V, F)
    floor = relative_area_floor * max(float(area.mean()), 1e-300)
    zero = area <= floor
    if zero.any():
        idx = np.flatnonzero(zero)
        raise MeshError(f"{role}: {idx.size} faces have zero area (first {_first(idx)}); {fix}")
    srt = np.sort(F, axis=1)
    count = np.unique(srt, axis=0, return_counts=True)[1]
    if (count > 1).any():
        raise MeshError(
            f"{role}: {int((count > 1).sum())} faces are duplicated (same three vertices); {fix}"
        )
    manifold = igl.is_edge_manifold(F)[0]
    if not manifold:
        E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
        uniq, cnt = np.unique(E, axis=0, return_counts=True)
        bad = uniq[cnt > 2]
        raise MeshError(
            f"{role}: {len(bad)} edges are shared by more than two faces (non-manifold; first "
            f"{bad[:3].tolist()}); {fix}"
        )
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    _, dcount = np.unique(directed, axis=0, return_counts=True)
    if (dcount > 1).any():
        raise MeshError(
            f"{role}: {int((dcount > 1).sum())} edges are traversed twice in the same direction "
            f"(faces inconsistently oriented); {fix} — it orients faces consistently"
        )
    used = np.zeros(mesh.n_vertices, dtype=bool)
    used[F.reshape(-1)] = True
    if role == "guest":
        pos, inverse = np.unique(mesh.V[used], axis=0, return_inverse=True)
        if len(pos) < int(used.sum()):
            dup = np.flatnonzero(used)[np.bincount(inverse.ravel())[inverse.ravel()] > 1]
            raise MeshError(
                f"guest: {dup.size} vertices share their position with another vertex "
                f"(duplicates, first {_first(dup)}); they split the surface into pieces — {fix}"
            )
    vm = np.ones(mesh.n_vertices, dtype=bool)
    flags = np.asarray(igl.is_vertex_manifold(F), dtype=bool)  # sized by the largest index
    vm[: len(flags)] = flags
    bad_v = np.flatnonzero(~vm & used)
    if bad_v.size:
        raise MeshError(
            f"{role}: {bad_v.size} vertices are non-manifold (their faces form separate fans; "
            f"first {_first(bad_v)}); {fix}"
        )
    if role == "guest" and not used.all():
        idx = np.flatnonzero(~used)
        raise MeshError(
            f"guest: {idx.size} vertices are not used by any face (unreferenced; first "
            f"{_first(idx)}); they cannot be deformed — {fix}"
        )


def check_guest_reaches_seam(F: np.ndarray, n: int, seam: np.ndarray) -> None:
    """Raise :class:`SolveError` if a guest component has no seam vertex or nothing is free.

    Parameters
    ----------
    F : ndarray of int64, shape (m, 3)
        Refined guest faces.
    n : int
        Number of refined guest vertices.
    seam : ndarray of int64, shape (s,)
    """
    if np.unique(seam).size >= n:
        raise SolveError(
            "guest: every vertex lies on the seam, so there is nothing to deform (no free "
            "vertex); the guest needs interior vertices — refine it with "
            "igljoin.resample(guest, target_edge) (or resample = true in join.toml) or join a "
            "larger piece"
        )
    comp = np.asarray(igl.vertex_components(F), dtype=np.int64)
    touched = np.unique(comp[seam])
    loose = np.setdiff1d(np.unique(comp), touched)
    if loose.size:
        sizes = [int((comp == c).sum()) for c in loose[:5]]
        raise SolveError(
            f"guest: {loose.size} connected components do not touch the seam (vertex counts "
            f"{sizes}); nothing holds them in place — remove them or join each with its own "
            "seam"
        )
