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

With several seams every seam is welded this way in the same mesh: each
seam's host edges are split and its vertices shared. The inputs are plain
arrays and one :class:`SeamRecord` per seam; ``JoinResult.merged`` passes
those of a join.

The result is checked (edge-manifold, vertex-manifold, every interior edge
used once in each direction, no zero-area face); a failure raises
:class:`~igljoin.errors.WeldError` naming the seam vertices involved.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import igl
import numpy as np

from . import metrics, topology
from .correspond import split_boundary_faces
from .errors import CurveError, WeldError
from .mesh import Mesh
from .polyline import mean_segment
from .validate import relative_area_floor

__all__ = ["SeamRecord", "Welded", "weld", "check_welded", "HOST", "GUEST"]

#: :attr:`Welded.label` / :attr:`Welded.source` code of the host.
HOST = 0
#: :attr:`Welded.label` / :attr:`Welded.source` code of the guest.
GUEST = 1

#: A guest seam vertex may be this many host seam edge lengths off the host
#: curve (the seam is a hard constraint: only rounding separates them).
SEAM_TOLERANCE = 1e-6

_SHOWN = 10  # offending vertices listed in an error message


@dataclass(frozen=True, eq=False)
class SeamRecord:
    """Where the guest seam vertices of one seam lie on its host curve.

    Attributes
    ----------
    host_curve : ndarray of int64, shape (k,)
        Host curve vertices in curve order.
    seam : ndarray of int64, shape (s,)
        Guest seam vertices in curve order.
    closed : bool
        The curve is a loop.
    host_hit : ndarray of int64, shape (k,)
        For each host curve vertex, the position in ``seam`` of the guest
        vertex on it.
    host_edge : ndarray of int64, shape (s,)
        For each seam vertex, the segment of ``host_curve`` it lies on
        (segment ``j`` joins ``host_curve[j]`` and ``host_curve[j + 1]``,
        wrapping on a closed curve).
    host_edge_t : ndarray, shape (s,)
        Position within that segment, in ``[0, 1]``.
    """

    host_curve: np.ndarray
    seam: np.ndarray
    closed: bool
    host_hit: np.ndarray
    host_edge: np.ndarray
    host_edge_t: np.ndarray

    @property
    def guest_at_host(self) -> np.ndarray:
        """Guest vertex lying on each host curve vertex, shape (k,)."""
        return self.seam[self.host_hit]


@dataclass(frozen=True, eq=False)
class Welded:
    """Host and deformed guest as one mesh with shared seam vertices.

    Attributes
    ----------
    mesh : Mesh
        ``V`` shape (n, 3), ``F`` shape (m, 3): host faces (split ones
        replaced by fans) first, then guest faces. Vertex attributes
        ``seam`` (bool), ``source`` and ``source_id`` (int, the columns of
        :attr:`source`) and, when given to :func:`weld`, ``strain`` and
        ``displacement`` (float; 0 on host vertices, the guest's values on
        shared seam vertices); face attributes ``label`` (int),
        ``source_face`` (int: original host face a fan face was split from,
        or guest face id) and, when given, ``area_ratio`` (float; 1.0 on
        host faces). ``JoinResult.merged`` always has all of them.
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


def _records(seams: Sequence[SeamRecord]) -> list[SeamRecord]:
    """``seams`` as a non-empty list of :class:`SeamRecord`, or a :class:`WeldError`."""
    if isinstance(seams, SeamRecord):
        seams = [seams]
    if (
        not isinstance(seams, Sequence)
        or not seams
        or not all(isinstance(sm, SeamRecord) for sm in seams)
    ):
        raise WeldError(
            f"weld: seams must be a non-empty list of igljoin.weld.SeamRecord, got "
            f"{type(seams).__name__}; pass JoinResult.seams, or weld a result with "
            "JoinResult.weld()"
        )
    return list(seams)


def _per_element(values, n: int, name: str, element: str) -> np.ndarray | None:
    """``values`` as a float array of shape (n,), or ``None`` when not given."""
    if values is None:
        return None
    out = np.asarray(values, dtype=np.float64)
    if out.shape != (n,):
        raise WeldError(
            f"weld: {name} has shape {out.shape}; give one value per guest {element} ({n})"
        )
    return out


def weld(
    host_V: np.ndarray,
    host_F: np.ndarray,
    guest_V: np.ndarray,
    guest_F: np.ndarray,
    seams: Sequence[SeamRecord],
    *,
    strain: np.ndarray | None = None,
    displacement: np.ndarray | None = None,
    area_ratio: np.ndarray | None = None,
    check: bool = True,
) -> Welded:
    """Merge host and deformed guest into one mesh in which the seam vertices are shared.

    Parameters
    ----------
    host_V : ndarray, shape (n_h, 3)
    host_F : ndarray of int, shape (m_h, 3)
        The rigid host.
    guest_V : ndarray, shape (n_g, 3)
    guest_F : ndarray of int, shape (m_g, 3)
        The deformed guest, its seams held on the host curves.
    seams : sequence of SeamRecord
        Where each seam's guest vertices lie on its host curve
        (``JoinResult.seams``).
    strain, displacement : ndarray, shape (n_g,), optional
        Per guest vertex; become vertex attributes of the welded mesh (0 on
        host vertices).
    area_ratio : ndarray, shape (m_g,), optional
        Per guest face; becomes a face attribute (1.0 on host faces).
    check : bool
        Validate the result (see :func:`check_welded`).

    Returns
    -------
    Welded
        ``(n_h + (s − k)) + n_g − s = n_h + n_g − k`` vertices and
        ``m_h + (s − k) + m_g`` faces: the ``s`` guest seam vertices are
        shared, ``k`` of them with host curve vertices and ``s − k`` with
        vertices inserted into host curve edges (each insertion splits one
        host triangle in two). With several seams, ``s`` and ``k`` are the
        totals over the seams.

    Raises
    ------
    WeldError
        The seams are not :class:`SeamRecord` objects, the guest seam is not
        on the host curve, the guest would have to be flipped for some seams
        and not for others (open curves on hosts facing different ways), or
        the merged mesh would be non-manifold, inconsistently oriented or
        have zero-area faces; the message names the seam vertices involved.

    Examples
    --------
    >>> import igljoin
    >>> from igljoin.weld import weld
    >>> s = igljoin.phantoms.paper_sample("end_to_end", "equal", resolution=0.4)
    >>> res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
    >>> w = weld(res.host.V, res.host.F, res.guest.V, res.guest.F, res.seams)
    >>> w.mesh.n_vertices == s.host.n_vertices + res.guest.n_vertices - len(res.host_curve)
    True
    """
    records = _records(seams)
    Vh = np.asarray(host_V, dtype=np.float64)
    Fh = np.asarray(host_F, dtype=np.int64)
    X = np.asarray(guest_V, dtype=np.float64)
    Fg = np.asarray(guest_F, dtype=np.int64)
    nh, ng = len(Vh), len(X)
    strain = _per_element(strain, ng, "strain", "vertex")
    displacement = _per_element(displacement, ng, "displacement", "vertex")
    area_ratio = _per_element(area_ratio, len(Fg), "area_ratio", "face")
    several = len(records) > 1

    # where each seam vertex lies on its host curve: on a host vertex (hit) or inside an edge
    hit_guest, hit_host = [], []
    split_guest, split_a, split_b, split_t, split_P = [], [], [], [], []
    for i, sm in enumerate(records):
        hc = np.asarray(sm.host_curve, dtype=np.int64)
        seam = np.asarray(sm.seam, dtype=np.int64)
        k, s = len(hc), len(seam)
        at_vertex = np.full(s, -1, dtype=np.int64)
        at_vertex[np.asarray(sm.host_hit, dtype=np.int64)] = np.arange(k)
        split = np.flatnonzero(at_vertex < 0)
        hit = np.flatnonzero(at_vertex >= 0)
        e = np.asarray(sm.host_edge, dtype=np.int64)
        t = np.asarray(sm.host_edge_t, dtype=np.float64)
        a, b = hc[e], hc[(e + 1) % k]
        P = Vh[a] * (1.0 - t)[:, None] + Vh[b] * t[:, None]
        P[hit] = Vh[hc[at_vertex[hit]]]
        scale = mean_segment(Vh[hc], bool(sm.closed))
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
    mseams = [g2m[np.asarray(sm.seam, dtype=np.int64)] for sm in records]
    all_seam = np.concatenate(mseams)
    host_keys = _directed_keys(Fh2[metrics.ring_band(Fh2, all_seam, 1)], n)
    guest_keys = _directed_keys(Fg2[metrics.ring_band(Fg2, all_seam, 1)], n)
    same, opposite = [], []
    for i, (mseam, sm) in enumerate(zip(mseams, records)):
        u = mseam if sm.closed else mseam[:-1]
        v = np.roll(mseam, -1) if sm.closed else mseam[1:]
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
    vertex_attributes = {"seam": seam_flag, "source": source[:, 0], "source_id": source[:, 1]}
    for name, values in (("strain", strain), ("displacement", displacement)):
        if values is not None:
            merged = np.zeros(n)
            merged[g2m] = values
            vertex_attributes[name] = merged
    face_attributes = {
        "label": label,
        "source_face": np.concatenate([parent, np.arange(mg, dtype=np.int64)]),
    }
    if area_ratio is not None:
        face_attributes["area_ratio"] = np.concatenate([np.ones(mh), area_ratio])
    mesh = Mesh(
        V, F, vertex_attributes=vertex_attributes, face_attributes=face_attributes, name="welded"
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


def check_welded(welded: Welded, *, full: bool = False) -> None:
    """Raise :class:`WeldError` unless the welded mesh is a clean oriented manifold.

    Checks that every edge has one or two faces and the faces around every
    vertex form one fan (:func:`igljoin.topology.edges`,
    :func:`igljoin.topology.vertex_manifold`, as ``igl.is_edge_manifold`` and
    ``igl.is_vertex_manifold`` decide), that every interior edge is used once
    in each direction (consistent orientation), and that no face has zero
    area (``igl.doublearea`` against
    :data:`igljoin.validate.relative_area_floor`).

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
    in_sub = np.zeros(n, dtype=bool)
    in_sub[sub.reshape(-1)] = True
    ids = np.flatnonzero(in_sub)
    lookup = np.zeros(n, dtype=np.int64)
    lookup[ids] = np.arange(len(ids))
    local = lookup[sub]
    half = topology.half_edges(local, len(ids))
    start, faces_at_edge = topology.runs(half[3])
    crowded = faces_at_edge > 2
    if crowded.any():
        E = np.stack(np.divmod(half[3][start[crowded]], len(ids)), axis=1)
        raise WeldError(
            f"weld: {int(crowded.sum())} edges have more than two faces "
            f"{_offenders(welded, ids[E])}; a guest triangle across the seam duplicates "
            "a host edge there — refine the guest near the seam (igljoin.clean) or pick curves "
            "that do not cut corners"
        )
    used = np.zeros(n, dtype=bool)
    used[(F if full else welded.seam).reshape(-1)] = True
    vm = np.zeros(n, dtype=bool)
    vm[ids] = topology.vertex_manifold(local, len(ids), half)
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
    floor = relative_area_floor * max(float(area.mean()), 1e-300)
    flat = np.flatnonzero(~(area > floor))
    if flat.size:
        raise WeldError(
            f"weld: {flat.size} faces have zero area {_offenders(welded, checked[flat])}; a guest "
            "seam vertex coincides with a host vertex it was not matched to — raise "
            "snap_fraction or refine the guest near the seam"
        )
