"""Weld the rigid host and the deformed guest into one conforming mesh.

The merged mesh holds every host vertex (ids ``0 .. n_h − 1``, unchanged),
then every guest vertex that does not land on a host curve vertex, in guest
order. Along the seam the two surfaces share vertices:

* a guest seam vertex on a host curve vertex *is* that host vertex;
* a guest seam vertex inside a host curve edge (``Correspondence.host_edge``,
  ``host_edge_t``) becomes a new host vertex there: the host boundary
  triangle of that edge is split into a fan. The host is rigid, so the
  vertex is placed exactly on the host edge and the fan covers exactly the
  old triangle; nothing moves. In :attr:`Welded.source` such a vertex maps
  to the guest vertex it coincides with (``(1, guest id)``): it is a guest
  vertex that the host adopted, and the guest is where its values
  (strain, displacement) come from.

With several seams (``JoinResult.seams``) every seam is welded this way in
the same mesh: each seam's host edges are split and its vertices shared.

The result is checked (edge-manifold, vertex-manifold, every interior edge
used once in each direction, no zero-area face); a failure raises
:class:`~igljoin.errors.WeldError` naming the seam vertices involved.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import igl
import numpy as np

from . import metrics
from .correspond import split_boundary_faces
from .errors import CurveError, WeldError
from .mesh import Mesh

if TYPE_CHECKING:
    from .result import JoinResult

__all__ = ["Welded", "weld", "check_welded", "HOST", "GUEST"]

#: :attr:`Welded.label` / :attr:`Welded.source` code of the host.
HOST = 0
#: :attr:`Welded.label` / :attr:`Welded.source` code of the guest.
GUEST = 1

#: A guest seam vertex may be this many host seam edge lengths off the host
#: curve (the seam is a hard constraint: only rounding separates them).
SEAM_TOLERANCE = 1e-6

#: Faces with less than this fraction of the mean face area count as degenerate.
AREA_FLOOR = 1e-12

_SHOWN = 10  # offending vertices listed in an error message


@dataclass(frozen=True, eq=False)
class Welded:
    """Host and deformed guest as one mesh with shared seam vertices.

    Attributes
    ----------
    mesh : Mesh
        ``V`` shape (n, 3), ``F`` shape (m, 3): host faces (split ones
        replaced by fans) first, then guest faces. Vertex attributes
        ``seam`` (bool), ``source`` and ``source_id`` (int, the columns of
        :attr:`source`), ``strain`` and ``displacement`` (float; 0 on host
        vertices, the guest's values on shared seam vertices); face
        attributes ``label`` (int), ``source_face`` (int: original host face
        a fan face was split from, or guest face id) and ``area_ratio``
        (float; 1.0 on host faces).
    source : ndarray of int64, shape (n, 2)
        For each merged vertex ``(source, id)``: ``(0, host vertex id)`` or
        ``(1, guest vertex id)`` (ids of ``JoinResult.host`` and
        ``JoinResult.guest``). Vertices inserted into host edges map to the
        guest vertex they coincide with.
    label : ndarray of int64, shape (m,)
        0 for a host face, 1 for a guest face.
    seam_flag : ndarray of bool, shape (n,)
        True on the shared seam vertices.
    flipped_guest : bool
        The guest faces were reversed to orient the merged mesh consistently
        (possible for open curves; never for closed curves, whose guest seam
        is paired against the host's face-induced direction).
    seam : ndarray of int64, shape (s,)
        Merged ids of the seam vertices in curve order (with several seams,
        seam after seam).
    n_splits : int
        Host curve edge splits, i.e. seam vertices that are not host vertices.
    seams : tuple of ndarray of int64
        Merged ids of each seam's vertices in curve order, shape (s_i,) each.
    """

    mesh: Mesh
    source: np.ndarray
    label: np.ndarray
    seam_flag: np.ndarray
    flipped_guest: bool
    seam: np.ndarray
    n_splits: int
    seams: tuple = ()

    @property
    def n_shared(self) -> int:
        """Number of vertices shared by host and guest (the seam)."""
        return int(len(self.seam))

    def summary(self) -> dict:
        """Plain-JSON counts of the welded mesh."""
        return {
            "vertices": self.mesh.n_vertices,
            "faces": self.mesh.n_faces,
            "shared": self.n_shared,
            "host_edge_splits": int(self.n_splits),
            "flipped_guest": bool(self.flipped_guest),
        }


def _guest_vertex_maps(result: JoinResult) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex strain and displacement of the deformed guest, each shape (n_g,)."""
    attrs = result.guest.vertex_attributes
    X, F = result.guest.V, result.guest.F
    rest = result.rest_guest.V
    if "strain" in attrs:
        strain = np.asarray(attrs["strain"], dtype=np.float64)
    else:
        E = np.asarray(igl.edges(F), dtype=np.int64)
        strain = metrics.vertex_strain(E, metrics.edge_strain(rest, X, E), len(X))
    if "displacement" in attrs:
        disp = np.asarray(attrs["displacement"], dtype=np.float64)
    else:
        disp = metrics.nonrigid_displacement(rest, X)
    return strain, disp


def _seam_parts(result: JoinResult) -> list[tuple]:
    """Per seam ``(host_curve, seam, closed, host_hit, host_edge, host_edge_t)`` of a result.

    From ``result.seams``; a result without them (built by hand) is one seam
    described by ``host_curve``, ``seam``, ``closed`` and ``correspondence``.
    """
    seams = getattr(result, "seams", None)
    if seams:
        return [
            (
                np.asarray(sm.host_curve, dtype=np.int64),
                np.asarray(sm.seam, dtype=np.int64),
                bool(sm.closed),
                np.asarray(sm.host_hit, dtype=np.int64),
                sm.host_edge,
                sm.host_edge_t,
            )
            for sm in seams
        ]
    c = result.correspondence
    return [
        (
            np.asarray(result.host_curve, dtype=np.int64),
            np.asarray(result.seam, dtype=np.int64),
            bool(result.closed),
            np.asarray(c.host_hit, dtype=np.int64),
            c.host_edge,
            c.host_edge_t,
        )
    ]


def _directed_keys(F: np.ndarray, n: int) -> np.ndarray:
    """Sorted keys ``u * n + v`` of the directed edges ``u -> v`` of faces ``F`` (m, 3) -> (3m,)."""
    FT = np.ascontiguousarray(F.T)  # (3, m)
    key = np.concatenate([FT[0] * n + FT[1], FT[1] * n + FT[2], FT[2] * n + FT[0]])
    key.sort()
    return key


def _directed_count(keys: np.ndarray, u: np.ndarray, v: np.ndarray, n: int) -> np.ndarray:
    """How many of the sorted directed-edge ``keys`` are ``u[i] -> v[i]``, shape (len(u),)."""
    q = u * n + v
    return np.searchsorted(keys, q, side="right") - np.searchsorted(keys, q, side="left")


def weld(result: JoinResult, *, check: bool = True) -> Welded:
    """Merge host and deformed guest into one mesh in which the seam vertices are shared.

    Parameters
    ----------
    result : JoinResult
        A join whose seam was held on the host curve (``solve()`` with the
        default targets).
    check : bool
        Validate the result (see :func:`check_welded`).

    Returns
    -------
    Welded
        ``(n_h + (s − k)) + n_g − s = n_h + n_g − k`` vertices and
        ``m_h + (s − k) + m_g`` faces: the ``s`` guest seam vertices are
        shared, ``k`` of them with host curve vertices and ``s − k`` with
        vertices inserted into host curve edges (each insertion splits one
        host triangle in two). ``n_g``, ``m_g`` count the refined guest
        (``result.guest``). With several seams, ``s`` and ``k`` are the
        totals over the seams.

    Raises
    ------
    WeldError
        The guest seam is not on the host curve, the guest would have to be
        flipped for some seams and not for others (open curves on hosts
        facing different ways), or the merged mesh would be non-manifold,
        inconsistently oriented or have zero-area faces; the message names
        the seam vertices involved.

    Examples
    --------
    >>> import igljoin
    >>> from igljoin.weld import weld
    >>> s = igljoin.phantoms.paper_sample("end_to_end", "equal", resolution=0.4)
    >>> res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
    >>> w = weld(res)  # the same as res.merged
    >>> w.mesh.n_vertices == s.host.n_vertices + res.guest.n_vertices - len(res.host_curve)
    True
    """
    c = getattr(result, "correspondence", None)
    if c is None or not hasattr(result, "host_curve"):
        raise WeldError(
            f"weld: expected an igljoin.JoinResult, got {type(result).__name__}; pass the "
            "result of igljoin.join(...) or JoinSolver.solve()"
        )
    Vh, Fh = result.host.V, result.host.F
    X, Fg = result.guest.V, result.guest.F
    nh, ng = len(Vh), len(X)
    parts = _seam_parts(result)
    several = len(parts) > 1

    # where each seam vertex lies on its host curve: on a host vertex (hit) or inside an edge
    hit_guest, hit_host = [], []
    split_guest, split_a, split_b, split_t, split_P = [], [], [], [], []
    for i, (hc, seam, closed, host_hit, host_edge, host_edge_t) in enumerate(parts):
        k, s = len(hc), len(seam)
        at_vertex = np.full(s, -1, dtype=np.int64)
        at_vertex[host_hit] = np.arange(k)
        split = np.flatnonzero(at_vertex < 0)
        hit = np.flatnonzero(at_vertex >= 0)
        e = np.asarray(host_edge, dtype=np.int64)
        t = np.asarray(host_edge_t, dtype=np.float64)
        a, b = hc[e], hc[(e + 1) % k]
        P = Vh[a] * (1.0 - t)[:, None] + Vh[b] * t[:, None]
        P[hit] = Vh[hc[at_vertex[hit]]]
        seg = np.diff(Vh[np.append(hc, hc[0]) if closed else hc], axis=0)
        scale = float(np.linalg.norm(seg, axis=1).mean())
        gap = np.linalg.norm(X[seam] - P, axis=1)
        off = np.flatnonzero(gap > SEAM_TOLERANCE * scale)
        if off.size:
            where = f"seam {i}: " if several else ""
            raise WeldError(
                f"weld: {where}{off.size} guest seam vertices are off the host curve by up to "
                f"{gap.max():.3g} ({gap.max() / scale:.3g} host seam edges; guest vertices "
                f"{seam[off][:_SHOWN].tolist()}); only a result whose seam is held on the host "
                "curve can be welded — solve with the default targets"
            )
        hit_guest.append(seam[hit])
        hit_host.append(hc[at_vertex[hit]])
        split_guest.append(seam[split])
        split_a.append(a[split])
        split_b.append(b[split])
        split_t.append(t[split])
        split_P.append(P[split])
    hit_guest, hit_host = np.concatenate(hit_guest), np.concatenate(hit_host)
    split_guest = np.concatenate(split_guest)
    split_a, split_b = np.concatenate(split_a), np.concatenate(split_b)
    split_t, split_P = np.concatenate(split_t), np.concatenate(split_P)

    # merged vertex ids of guest vertices: host curve vertex, or appended after the host
    drop = np.zeros(ng, dtype=bool)
    drop[hit_guest] = True
    keep = np.flatnonzero(~drop)
    g2m = np.empty(ng, dtype=np.int64)
    g2m[keep] = nh + np.arange(len(keep))
    g2m[hit_guest] = hit_host
    V = np.vstack([Vh, X[keep]])
    V[g2m[split_guest]] = split_P  # exactly on the host edge: the host does not move

    # split host boundary triangles into fans at the adopted guest vertices
    if split_guest.size:
        try:
            Fh2, parent = split_boundary_faces(Fh, split_a, split_b, split_t, nh)
        except CurveError:
            raise WeldError(
                "weld: a host curve edge belongs to no host face; the host curve must follow "
                "boundary edges of the host"
            ) from None
        new = Fh2 >= nh
        Fh2[new] = g2m[split_guest[Fh2[new] - nh]]
    else:
        Fh2, parent = Fh.copy(), np.arange(len(Fh), dtype=np.int64)
    Fg2 = g2m[Fg]

    # orientation: the two sides must use each seam edge in opposite directions; only
    # faces with a seam vertex can hold a seam edge
    n = len(V)
    mseams = [g2m[seam] for _, seam, *_ in parts]
    all_seam = np.concatenate(mseams)
    host_keys = _directed_keys(Fh2[metrics.ring_band(Fh2, all_seam, 1)], n)
    guest_keys = _directed_keys(Fg2[metrics.ring_band(Fg2, all_seam, 1)], n)
    same, opposite = [], []
    for i, (mseam, (_, _, closed, *_)) in enumerate(zip(mseams, parts)):
        u = mseam if closed else mseam[:-1]
        v = np.roll(mseam, -1) if closed else mseam[1:]
        host_dir = np.sign(
            _directed_count(host_keys, u, v, n).sum() - _directed_count(host_keys, v, u, n).sum()
        )
        guest_dir = np.sign(
            _directed_count(guest_keys, u, v, n).sum() - _directed_count(guest_keys, v, u, n).sum()
        )
        if host_dir != 0 and host_dir == guest_dir:
            same.append(i)
        elif host_dir != 0 and host_dir == -guest_dir:
            opposite.append(i)
    if same and opposite:
        raise WeldError(
            f"weld: the guest runs along the host at seams {same} but against it at seams "
            f"{opposite}; no orientation of the guest fits every host — reverse the faces of "
            "the host(s) of one group (F[:, ::-1]) so that all hosts face the same way"
        )
    flipped = bool(same)
    if flipped:
        Fg2 = Fg2[:, [0, 2, 1]]
    mseam = np.concatenate(mseams)

    F = np.vstack([Fh2, Fg2])
    mh, mg = len(Fh2), len(Fg2)
    label = np.repeat(np.array([HOST, GUEST], dtype=np.int64), [mh, mg])
    source = np.empty((n, 2), dtype=np.int64)
    source[:nh, 0], source[:nh, 1] = HOST, np.arange(nh)
    source[nh:, 0], source[nh:, 1] = GUEST, keep
    seam_flag = np.zeros(n, dtype=bool)
    seam_flag[mseam] = True

    # per-vertex maps: 0 on the rigid host, the guest's values on the shared seam
    strain, disp = _guest_vertex_maps(result)
    v_strain = np.zeros(n)
    v_disp = np.zeros(n)
    v_strain[g2m] = strain
    v_disp[g2m] = disp
    ratio = np.concatenate([np.ones(mh), np.asarray(result.area_ratio, dtype=np.float64)])
    mesh = Mesh(
        V,
        F,
        vertex_attributes={
            "seam": seam_flag,
            "source": source[:, 0],
            "source_id": source[:, 1],
            "strain": v_strain,
            "displacement": v_disp,
        },
        face_attributes={
            "label": label,
            "source_face": np.concatenate([parent, np.arange(mg, dtype=np.int64)]),
            "area_ratio": ratio,
        },
        name="welded",
    )
    welded = Welded(
        mesh=mesh,
        source=source,
        label=label,
        seam_flag=seam_flag,
        flipped_guest=flipped,
        seam=mseam,
        n_splits=int(split_guest.size),
        seams=tuple(mseams),
    )
    if check:
        check_welded(welded)
    return welded


def _offenders(welded: Welded, vertices: np.ndarray) -> str:
    """Describe offending vertices, seam vertices first, with their guest ids."""
    vertices = np.unique(np.asarray(vertices, dtype=np.int64))
    on_seam = vertices[welded.seam_flag[vertices]]
    if on_seam.size:
        src = welded.source[on_seam]
        guest = np.where(src[:, 0] == GUEST, src[:, 1], -1)
        return (
            f"at seam vertices {on_seam[:_SHOWN].tolist()} (merged ids; "
            f"{on_seam.size} in all; host/guest ids {src[:_SHOWN].tolist()}"
            + (f", guest ids {guest[guest >= 0][:_SHOWN].tolist()}" if (guest >= 0).any() else "")
            + ")"
        )
    return (
        f"away from the seam at vertices {vertices[:_SHOWN].tolist()} (merged ids; "
        f"{vertices.size} in all)"
    )


def _fans(F, n):
    """Edge-manifoldness and, per vertex, whether its faces form one edge-connected fan.

    The faces at a vertex ``v`` are linked when they share an edge (as
    ``igl.is_vertex_manifold`` links them); faces that both hold ``v``
    share an edge exactly when they share a second vertex. The vertex is
    manifold when the links join all its faces (union-find per vertex).

    Parameters
    ----------
    F : ndarray of int64, shape (m, 3)
        Faces using every vertex ``0 .. n − 1``, none repeating a vertex.
    n : int

    Returns
    -------
    edge_manifold : bool
        No edge has more than two faces (``igl.is_edge_manifold``).
    vertex_manifold : ndarray of bool, shape (n,)
        ``igl.is_vertex_manifold``.
    """
    m = F.shape[0]
    # faces at each vertex, in CSR form
    start = np.zeros(n + 1, dtype=np.int64)
    for f in range(m):
        for c in range(3):
            start[F[f, c] + 1] += 1
    for v in range(n):
        start[v + 1] += start[v]
    at = np.empty(3 * m, dtype=np.int64)
    fill = start[:-1].copy()
    for f in range(m):
        for c in range(3):
            at[fill[F[f, c]]] = f
            fill[F[f, c]] += 1
    edge_manifold = True
    vertex_manifold = np.zeros(n, dtype=np.bool_)
    parent = np.empty(3 * m, dtype=np.int64)  # union-find over the faces at one vertex
    seen = np.full(n, -1, dtype=np.int64)  # slot of a face at the vertex holding each vertex
    count = np.zeros(n, dtype=np.int64)  # faces at the vertex holding each vertex
    for v in range(n):
        lo, hi = start[v], start[v + 1]
        for s in range(lo, hi):
            parent[s] = s
        for s in range(lo, hi):
            f = at[s]
            for c in range(3):
                x = F[f, c]
                if x == v:
                    continue
                count[x] += 1
                if seen[x] < 0:
                    seen[x] = s
                    continue
                a, b = s, seen[x]
                while parent[a] != a:
                    a = parent[a]
                while parent[b] != b:
                    b = parent[b]
                parent[max(a, b)] = min(a, b)
        roots = 0
        for s in range(lo, hi):
            if parent[s] == s:
                roots += 1
            f = at[s]
            for c in range(3):
                x = F[f, c]
                if x != v:
                    if count[x] > 2:
                        edge_manifold = False
                    count[x] = 0
                    seen[x] = -1
        vertex_manifold[v] = roots == 1
    return edge_manifold, vertex_manifold


def _manifold_checks(F: np.ndarray, n: int):
    """:func:`_fans` of faces ``F`` (m, 3) on vertices ``0 .. n − 1``, or ``None``.

    ``None`` without numba or when a face repeats a vertex (libigl then decides).
    """
    if _fans_compiled is None:
        return None
    FT = np.ascontiguousarray(F.T)
    if ((FT[0] == FT[1]) | (FT[1] == FT[2]) | (FT[2] == FT[0])).any():
        return None
    return _fans_compiled(np.ascontiguousarray(F, dtype=np.int64), n)


try:
    import numba as _nb
except ImportError:  # without numba libigl runs both manifold checks
    _nb = None
#: :func:`_fans` compiled by numba (cached on disk), or ``None`` without numba.
_fans_compiled = None if _nb is None else _nb.njit(cache=True)(_fans)


def check_welded(welded: Welded, *, full: bool = False) -> None:
    """Raise :class:`WeldError` unless the welded mesh is a clean oriented manifold.

    Checks, with libigl where it has the routine: every edge has one or two
    faces (``igl.is_edge_manifold``), the faces around every vertex form one
    fan (``igl.is_vertex_manifold``), every interior edge is used once in
    each direction (consistent orientation), and no face has zero area
    (``igl.doublearea``).

    Parameters
    ----------
    welded : Welded
    full : bool
        Run every check on the whole mesh. By default the manifold and
        orientation checks run on the faces at the seam only (every edge
        welding creates or shares has a seam vertex, so all its faces are
        there; host and guest were checked when the join started,
        ``check_surface``), and the area check on those and on every guest
        face (the deformation moves them all).

    Raises
    ------
    WeldError
        Naming the seam vertices at the problem (or other vertices if the
        problem is away from the seam) and what to do.
    """
    V, F = welded.mesh.V, welded.mesh.F
    n = len(V)
    at_seam = None if full else metrics.ring_band(F, welded.seam, 1)
    sub = F if full else F[at_seam]
    # both manifold checks are combinatorial: run them on the sub-mesh's own vertex ids
    # (ascending, as np.unique numbers them), first by _fans (cheap), then, where it finds
    # a problem or cannot run, by libigl for the message
    in_sub = np.zeros(n, dtype=bool)
    in_sub[sub.reshape(-1)] = True
    ids = np.flatnonzero(in_sub)
    lookup = np.zeros(n, dtype=np.int64)
    lookup[ids] = np.arange(len(ids))
    local = lookup[sub]
    used = np.zeros(n, dtype=bool)
    used[(F if full else welded.seam).reshape(-1)] = True
    fans = _manifold_checks(local, len(ids))
    edges_ok = fans is not None and fans[0]
    vertices_ok = (
        fans is not None and used[ids].sum() == used.sum() and bool(fans[1][used[ids]].all())
    )
    manifold = True
    if not edges_ok:
        # libigl flags the *manifold* edges True in BE
        manifold, _, E, _, BE = igl.is_edge_manifold(local)
        E = ids[np.asarray(E, dtype=np.int64)]
        crowded = ~np.asarray(BE, dtype=bool).reshape(-1)
    if not manifold:
        raise WeldError(
            f"weld: {int(crowded.sum())} edges have more than two faces "
            f"{_offenders(welded, E[crowded])}; a guest triangle across the seam duplicates a host "
            "edge there — refine the guest near the seam (igljoin.clean) or pick curves that "
            "do not cut corners"
        )
    bad = np.zeros(0, dtype=np.int64)
    if not vertices_ok:
        vm = np.zeros(n, dtype=bool)
        vm[ids] = np.asarray(igl.is_vertex_manifold(local), dtype=bool).reshape(-1)
        bad = np.flatnonzero(~vm & used)
    if bad.size:
        raise WeldError(
            f"weld: {bad.size} vertices join separate fans of faces {_offenders(welded, bad)}; "
            "host and guest touch there other than along the seam — check that the curves "
            "are the joined boundaries and that the guest curve is a whole loop or path"
        )
    key = _directed_keys(sub, n)
    dup = np.unique(key[1:][key[1:] == key[:-1]])
    if dup.size:
        raise WeldError(
            f"weld: {dup.size} edges are used twice in the same direction "
            f"{_offenders(welded, np.stack([dup // n, dup % n], axis=1))}; the merged faces are "
            "not consistently oriented — orient the host and guest consistently "
            "(igl.bfs_orient) before joining"
        )
    checked = F if full else F[at_seam | (welded.label == GUEST)]
    area = igl.doublearea(V, checked)
    floor = AREA_FLOOR * max(float(area.mean()), 1e-300)
    flat = np.flatnonzero(~(area > floor))
    if flat.size:
        raise WeldError(
            f"weld: {flat.size} faces have zero area {_offenders(welded, checked[flat])}; a guest "
            "seam vertex coincides with a host vertex it was not matched to — raise "
            "snap_tolerance or refine the guest near the seam"
        )
