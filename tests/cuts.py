"""Cut a piece out of a closed real mesh, for ground-truth joins."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import igl
import numpy as np
from scipy.spatial.transform import Rotation

import igljoin


def sample_mesh_dir() -> Path:
    """Folder of real meshes shipped in the pymeshlab wheel."""
    import pymeshlab

    return Path(pymeshlab.__file__).parent / "tests" / "sample_meshes"


@dataclass
class Cut:
    host: igljoin.Mesh
    piece: igljoin.Mesh
    host_curve: np.ndarray  # ordered host loop along the cut
    piece_at_host: np.ndarray  # piece vertex on each host curve vertex
    diameter: float


def _submesh(V, F):
    used = np.unique(F)
    remap = np.full(len(V), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F], used


def cut_piece(mesh: igljoin.Mesh, center_vertex: int, radius: float) -> Cut | None:
    """Cut the faces within ``radius`` of a vertex (the connected patch around it).

    Returns None when the cut is not a clean disk with one boundary loop.
    """
    V, F = mesh.V, mesh.F
    near = np.linalg.norm(V - V[center_vertex], axis=1) <= radius
    inside = near[F].all(axis=1)
    # keep the edge-connected patch that contains the centre vertex
    _, comp = igl.facet_components(F[inside])
    seed = np.flatnonzero((F[inside] == center_vertex).any(axis=1))
    if not seed.size:
        return None
    patch_faces = np.flatnonzero(inside)[comp == comp[seed[0]]]
    mask = np.zeros(len(F), dtype=bool)
    mask[patch_faces] = True
    Vp, Fp, used_p = _submesh(V, F[mask])
    Vh, Fh, used_h = _submesh(V, F[~mask])
    loops_p = igljoin.boundary_loops(Fp)
    if len(loops_p) != 1:
        return None
    ne = len(igl.edges(Fp))
    if len(Vp) - ne + len(Fp) != 1:  # not a disk
        return None
    if not igl.is_edge_manifold(Fh)[0] or not np.asarray(igl.is_vertex_manifold(Fh)).all():
        return None
    host_of_orig = np.full(len(V), -1, dtype=np.int64)
    host_of_orig[used_h] = np.arange(len(used_h))
    piece_of_orig = np.full(len(V), -1, dtype=np.int64)
    piece_of_orig[used_p] = np.arange(len(used_p))
    loop_orig = used_p[loops_p[0]]
    host_curve = host_of_orig[loop_orig]
    if (host_curve < 0).any():
        return None
    host = igljoin.Mesh(Vh, Fh, name="host")
    loops_h = igljoin.boundary_loops(Fh)
    k = [i for i, lp in enumerate(loops_h) if host_curve[0] in lp]
    if len(k) != 1 or len(loops_h[k[0]]) != len(host_curve):
        return None
    host_loop = loops_h[k[0]]
    start = int(np.flatnonzero(host_loop == host_curve[0])[0])
    host_loop = np.roll(host_loop, -start)
    orig = used_h[host_loop]
    diameter = float(np.linalg.norm(np.ptp(Vp, axis=0)))
    return Cut(host, igljoin.Mesh(Vp, Fp, name="piece"), host_loop, piece_of_orig[orig], diameter)


def rigid_motion(seed: int, size: float, angle_deg: float = 40.0, shift: float = 0.25):
    """A rotation by ``angle_deg`` about a random axis and a shift of ``shift × size``."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    R = Rotation.from_rotvec(np.radians(angle_deg) * axis).as_matrix()
    d = rng.normal(size=3)
    t = shift * size * d / np.linalg.norm(d)
    return R, t
