"""The seams of a join: hosts, curves selected and paired, correspondences (§3, §4.1).

:class:`igljoin.JoinSolver` calls these in order:

1. :func:`load_hosts` — one host mesh, or several joined as one;
2. :func:`host_neighbourhood` / :func:`check_host` — a large host is read
   near its curves only;
3. :func:`select_seams` — each seam's host and guest curves resolved, checked
   (disjoint, comparable scales) and paired (guest vertex 0 on host vertex 0);
4. :func:`correspond_seams` — the paper's §4.1 seam after seam on the
   progressively refined guest, combined into one correspondence.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .boundary import Curve, SelectedCurve, select_curve
from .correspond import Correspondence, correspond, pair_seams
from .errors import CurveError, MeshError
from .mesh import Mesh, as_mesh
from .validate import check_guest_reaches_seam, check_seam_scales, check_surface

__all__ = [
    "SeamPair",
    "load_hosts",
    "host_neighbourhood",
    "check_host",
    "select_seams",
    "correspond_seams",
    "combined_correspondence",
]

_SHOWN = 5  # shared vertices listed in an error message


@dataclass(frozen=True)
class SeamPair:
    """The two curves of one seam, resolved and paired.

    Attributes
    ----------
    host_index : int
        Host mesh the curve is on (0 for a single host mesh).
    host_curve : SelectedCurve
        On the combined host (indices into ``JoinSolver.host``).
    guest_curve : SelectedCurve
        On the guest, paired: guest vertex 0 corresponds to host vertex 0.
    pairing : dict
        Rigid-fit residuals of the start search (see :func:`igljoin.correspond.pair_curves`).
    """

    host_index: int
    host_curve: SelectedCurve
    guest_curve: SelectedCurve
    pairing: dict = field(default_factory=dict)


def host_list(host: Any) -> list | None:
    """The host meshes if ``host`` is a list of meshes, else ``None`` (one mesh)."""
    if not isinstance(host, (list, tuple)) or not host:
        return None
    if all(isinstance(h, Mesh) for h in host):
        return list(host)
    if isinstance(host, list) and all(isinstance(h, tuple) and len(h) == 2 for h in host):
        return list(host)
    return None


def combined_host(hosts: list[Mesh]) -> tuple[Mesh, np.ndarray]:
    """Several host meshes as one mesh (vertices and faces concatenated) and vertex offsets.

    Parameters
    ----------
    hosts : list of Mesh
        ``h`` meshes.

    Returns
    -------
    combined : Mesh
        Vertices and faces of the meshes in order, faces renumbered.
    offsets : ndarray of int64, shape (h + 1,)
        Mesh ``i`` has the combined vertices ``offsets[i]:offsets[i + 1]``.
    """
    offsets = np.cumsum([0] + [h.n_vertices for h in hosts]).astype(np.int64)
    V = np.vstack([h.V for h in hosts])
    F = np.vstack([h.F + o for h, o in zip(hosts, offsets)])
    return Mesh(V, F, name="host"), offsets


def seam_specs(seams: Any, n_hosts: int, host_list: bool) -> list[tuple[int | None, Any, Any]]:
    """``(host index or None, host curve spec, guest curve spec)`` per seam, validated."""
    if isinstance(seams, (str, bytes, Mapping)) or not isinstance(seams, Sequence) or not seams:
        raise CurveError(
            "seams must be a non-empty list of (host_curve, guest_curve) or (host_index, "
            f"host_curve, guest_curve) tuples, got {seams!r:.80}"
        )
    out = []
    for i, item in enumerate(seams):
        if not isinstance(item, (tuple, list)) or len(item) not in (2, 3):
            raise CurveError(
                f"seams[{i}] must be a (host_curve, guest_curve) or (host_index, host_curve, "
                f"guest_curve) tuple, got {item!r:.80}"
            )
        if len(item) == 2:
            out.append((None, item[0], item[1]))
            continue
        index = item[0]
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
            raise CurveError(
                f"seams[{i}]: the first of three entries is the host index and must be an "
                f"integer, got {index!r:.40}; give (host_index, host_curve, guest_curve) or "
                "(host_curve, guest_curve)"
            )
        if not 0 <= int(index) < n_hosts:
            what = f"there are {n_hosts} host meshes" if host_list else "there is one host mesh"
            raise CurveError(
                f"seams[{i}]: host index {int(index)} does not exist; {what} "
                f"(indices 0..{n_hosts - 1}) — pass host=[mesh0, mesh1, ...] to join several"
            )
        out.append((int(index), item[1], item[2]))
    return out


def check_disjoint(pairs: list[SeamPair]) -> None:
    """Raise :class:`CurveError` if two seams share a host or a guest vertex."""
    for side in ("guest", "host"):
        curves = [getattr(p, f"{side}_curve").indices for p in pairs]
        owner = np.concatenate([np.full(len(c), i) for i, c in enumerate(curves)])
        ids = np.concatenate(curves)
        order = np.argsort(ids, kind="stable")
        same = np.flatnonzero(ids[order][1:] == ids[order][:-1])
        if not same.size:
            continue
        i, j = sorted({int(owner[order[same[0]]]), int(owner[order[same[0] + 1]])})
        shared = np.intersect1d(curves[i], curves[j])
        raise CurveError(
            f"seams[{i}] and seams[{j}] share {shared.size} {side} vertices "
            f"({shared[:_SHOWN].tolist()}); each boundary vertex can belong to one seam only — "
            f"give {side} curves that neither overlap nor touch (different loops, or open "
            "curves with a gap between them)"
        )


def combined_correspondence(parts: list[Correspondence], host_sizes: list[int]) -> Correspondence:
    """The correspondences of consecutive seams as one (see ``JoinResult.correspondence``).

    Parameters
    ----------
    parts : list of Correspondence
        One per seam, each made on the guest refined by the ones before it
        (:func:`correspond_seams`).
    host_sizes : list of int
        The number of host curve vertices of each seam (``k_i``).

    Returns
    -------
    Correspondence
        ``V``, ``F`` of the last part (the guest refined on every seam),
        ``face_parent`` composed back to the guest as given, and the per-seam
        arrays concatenated seam after seam: ``seam``, ``seam_t``,
        ``host_edge_t`` shape (s,), ``targets`` shape (s, 3), ``host_hit``
        shape (k,) indexing the concatenated ``seam``, ``host_edge`` shape
        (s,) indexing the concatenated host curves (``s``, ``k`` the totals).
        A single part is returned as it is.
    """
    if len(parts) == 1:
        return parts[0]
    last = parts[-1]
    parent = parts[0].face_parent
    for c in parts[1:]:
        parent = parent[c.face_parent]
    seam_off = np.cumsum([0] + [len(c.seam) for c in parts[:-1]])
    host_off = np.cumsum([0] + host_sizes[:-1])
    return Correspondence(
        V=last.V,
        F=last.F,
        face_parent=parent,
        n_original=parts[0].n_original,
        seam=np.concatenate([c.seam for c in parts]),
        targets=np.vstack([c.targets for c in parts]),
        seam_t=np.concatenate([c.seam_t for c in parts]),
        host_hit=np.concatenate([c.host_hit + o for c, o in zip(parts, seam_off)]),
        host_edge=np.concatenate([c.host_edge + o for c, o in zip(parts, host_off)]),
        host_edge_t=np.concatenate([c.host_edge_t for c in parts]),
        inserted_from=np.vstack([c.inserted_from.reshape(-1, 2) for c in parts]),
        inserted_t=np.concatenate([c.inserted_t for c in parts]),
    )


# the host neighbourhood reaches at least this many of the longest curve edges beyond the
# curves (the bands the join measures are a few edges wide)
_NEAR_EDGES = 10


def _given_indices(spec: Any) -> np.ndarray | None:
    """The vertex indices of a curve given as an index array (or ``Curve(indices=...)``)."""
    if isinstance(spec, Curve):
        spec = spec.indices
    elif isinstance(spec, Mapping):
        spec = spec.get("indices")
    elif spec is None or isinstance(spec, (int, np.integer, str, bytes)):
        return None
    try:
        idx = np.asarray(spec)
    except (TypeError, ValueError):
        return None
    if idx.ndim != 1 or idx.size == 0 or not np.issubdtype(idx.dtype, np.integer):
        return None
    return idx.astype(np.int64)


def _renamed(mesh: Mesh, name: str) -> Mesh:
    """``Mesh(mesh.V, mesh.F, name=name)`` without copying the (read-only) arrays."""
    out = copy.copy(mesh)
    object.__setattr__(out, "name", name)
    object.__setattr__(out, "vertex_attributes", {})
    object.__setattr__(out, "face_attributes", {})
    return out


def host_neighbourhood(
    host: Mesh, host_curve: Any, seams: Any, max_faces: int = 200_000
) -> Mesh | None:
    """The part of a large single host that the join uses, or ``None`` to use all of it.

    The host is rigid: the join reads it only around its curves (their
    frames, the crease and dihedral bands, the weld's seam faces and the
    self-intersection band). For a host of more than
    ``max_faces`` faces (:data:`igljoin.join.HOST_CHECK_ALL_FACES`) whose
    curves are all given by vertex
    indices this is the mesh of the faces that have a vertex within half a
    curve diameter (at least :data:`_NEAR_EDGES` curve edges) of the curves'
    bounding box — a physical neighbourhood that contains every band the
    join measures (a few edges wide); every vertex inside it keeps all its
    faces — on the host's own vertex ids. Smaller hosts, and
    curves selected by loop or start vertex (which need all of the host's
    boundary), get ``None``.

    Parameters
    ----------
    host : Mesh
        A single host mesh.
    host_curve, seams
        As given to :class:`igljoin.JoinSolver` (``seams`` ``None`` for a
        single seam given by ``host_curve``).
    max_faces : int
        Hosts of at most this many faces are used whole.

    Returns
    -------
    Mesh or None
        ``V`` the host's own (n_h, 3) array, ``F`` shape (m', 3) the faces
        near the curves; ``None`` to use the whole host.
    """
    specs = (
        [host_curve]
        if seams is None
        else [
            item[-2] if isinstance(item, (tuple, list)) and len(item) in (2, 3) else None
            for item in (seams if isinstance(seams, Sequence) else [])
        ]
    )
    curves = [_given_indices(spec) for spec in specs]
    n = host.n_vertices
    if (
        host.n_faces <= max_faces
        or not curves
        or any(c is None or c.min() < 0 or c.max() >= n for c in curves)
        or (seams is not None and any(len(item) == 3 for item in seams))
    ):
        return None
    P = host.V[np.concatenate(curves)]
    lo, hi = P.min(axis=0), P.max(axis=0)
    longest = max(
        float(np.linalg.norm(np.diff(host.V[c], axis=0), axis=1).max(initial=0.0)) for c in curves
    )
    pad = max(0.5 * float(np.linalg.norm(hi - lo)), _NEAR_EDGES * longest)
    near = ((host.V >= lo - pad) & (host.V <= hi + pad)).all(axis=1)
    F = host.F[near[host.F].any(axis=1)]
    if not len(F):
        return None  # curves on no face: the whole-host path reports it
    return Mesh(host.V, F, name=host.name)


def check_host(host: Mesh, near: Mesh | None) -> None:
    """``check_surface`` of a single host, on its neighbourhood ``near`` when given.

    Where the neighbourhood fails a check the whole host is checked, so an
    error always names the right elements and a fan cut at the
    neighbourhood's rim is never reported. Defects farther away do not
    enter the join and stay in the host as given.

    Parameters
    ----------
    host : Mesh
    near : Mesh or None
        :func:`host_neighbourhood` of ``host``.

    Raises
    ------
    MeshError
        The message of the whole host's :func:`igljoin.validate.check_surface`.
    """
    if near is None:
        check_surface(host, "host")
        return
    try:
        check_surface(near, "host")
    except MeshError:
        check_surface(host, "host")


def select_near(host: Mesh, near: Mesh, spec: Any, name: str) -> SelectedCurve:
    """A host curve given by indices, selected on the host's neighbourhood ``near``.

    Every curve vertex lies inside the neighbourhood with all its faces, so
    its boundary edges, their loop order and direction, and whether the
    curve is a whole loop are the host's; only the loop's number is not
    (``loop=-1``: the host's loops were not all traced). Where the
    selection fails, it is repeated on the whole host for the error message.
    """
    try:
        hc = select_curve(near, spec, name=name)
    except CurveError:
        return select_curve(host, spec, name=name)
    return SelectedCurve(hc.indices, hc.closed, -1, hc.forward)


def load_hosts(host: Any) -> tuple[list[Mesh], Mesh, np.ndarray, bool]:
    """The host meshes as given, the combined host and its vertex offsets.

    Parameters
    ----------
    host : Mesh or (V, F), or list of them

    Returns
    -------
    hosts : list of Mesh
        One per host mesh (one for a single mesh), named ``host`` or ``host[i]``.
    combined : Mesh
        The host meshes as one (vertices and faces concatenated).
    offsets : ndarray of int64, shape (h + 1,)
        Host mesh ``i`` has the combined vertices ``offsets[i]:offsets[i + 1]``.
    several : bool
        ``host`` was a list of meshes.
    """
    hosts = host_list(host)
    if hosts is None:
        one = as_mesh(host, "host")
        if one.name == "mesh":
            one = _renamed(one, "host")
        return [one], one, np.array([0, one.n_vertices], dtype=np.int64), False
    meshes = [as_mesh(h, f"host[{i}]") for i, h in enumerate(hosts)]
    meshes = [_renamed(h, f"host[{i}]") if h.name == "mesh" else h for i, h in enumerate(meshes)]
    combined, offsets = combined_host(meshes)
    return meshes, combined, offsets, True


def _select(
    hosts: list[Mesh],
    host: Mesh,
    offsets: np.ndarray,
    near: Mesh | None,
    guest: Mesh,
    index: int | None,
    hspec: Any,
    gspec: Any,
    hname: str,
    gname: str,
) -> SeamPair:
    """Resolve the curves of one seam (not yet paired; ``pairing`` holds ``start_given``)."""
    if index is None and near is not None:
        hc = select_near(host, near, hspec, hname)
        index = 0
    elif index is None:
        hc = select_curve(host, hspec, name=hname)
        index = int(np.searchsorted(offsets, hc.indices[0], side="right") - 1)
    else:
        sub = select_curve(hosts[index], hspec, name=hname)
        if len(hosts) == 1:
            hc = sub
        else:
            off = int(offsets[index])
            hc = select_curve(host, Curve(indices=sub.indices + off, closed=sub.closed), name=hname)
    g = Curve.coerce(gspec, gname)
    gc = select_curve(guest, g, name=gname)
    start_given = g.start is not None or g.indices is not None
    return SeamPair(index, hc, gc, {"start_given": start_given})


def select_seams(
    hosts: list[Mesh],
    host: Mesh,
    offsets: np.ndarray,
    near: Mesh | None,
    guest: Mesh,
    host_curve: Any,
    guest_curve: Any,
    seams: Any,
    several_hosts: bool,
) -> list[SeamPair]:
    """Resolve, check and pair the curves of every seam.

    Parameters
    ----------
    hosts, host, offsets
        As :func:`load_hosts` returns them.
    near : Mesh or None
        The host's neighbourhood of its curves (:func:`host_neighbourhood`).
    guest : Mesh
    host_curve, guest_curve, seams
        As given to :class:`igljoin.JoinSolver` (``seams`` or the two curves).
    several_hosts : bool
        The host was given as a list of meshes.

    Returns
    -------
    list of SeamPair
        Paired: each guest curve's vertex 0 corresponds to its host curve's.

    Raises
    ------
    CurveError
        Both ``seams`` and single curves given, a malformed seam, seams that
        share a vertex, or a curve that cannot be selected.
    """
    if seams is None:
        specs = [(None, host_curve, guest_curve)]
        names = [("host_curve", "guest_curve")]
    else:
        if host_curve is not None or guest_curve is not None:
            raise CurveError(
                "give either seams=[(host_curve, guest_curve), ...] or host_curve and "
                "guest_curve, not both; put the single seam into the seams list"
            )
        specs = seam_specs(seams, len(hosts), several_hosts)
        names = [(f"seams[{i}] host curve", f"seams[{i}] guest curve") for i in range(len(specs))]
    resolved = [
        _select(hosts, host, offsets, near, guest, *spec, *name) for spec, name in zip(specs, names)
    ]
    check_disjoint(resolved)
    check_seam_scales(host.V, guest.V, resolved)
    paired = pair_seams(
        host.V,
        [r.host_curve for r in resolved],
        guest.V,
        [r.guest_curve for r in resolved],
        guest_starts_given=[bool(r.pairing["start_given"]) for r in resolved],
    )
    return [SeamPair(r.host_index, hc, gc, info) for r, (hc, gc, info) in zip(resolved, paired)]


def correspond_seams(
    V: np.ndarray, F: np.ndarray, host_V: np.ndarray, pairs: list[SeamPair], snap_fraction: float
) -> tuple[list[Correspondence], Correspondence]:
    """The paper's §4.1 for every seam, on the guest refined by the seams before it.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray of int64, shape (m, 3)
        The rest guest.
    host_V : ndarray, shape (n_h, 3)
        The (combined) host's vertices.
    pairs : list of SeamPair
    snap_fraction : float
        See :func:`igljoin.correspond.correspond`.

    Returns
    -------
    parts : list of Correspondence
        One per seam; the last one's ``V``, ``F`` are the fully refined guest.
    combined : Correspondence
        All of them as one (see ``JoinResult.correspondence``).

    Raises
    ------
    MeshError
        If a guest component does not reach any seam (nothing would hold it).
    """
    parts = []
    for p in pairs:
        part = correspond(V, F, p.guest_curve, host_V, p.host_curve, snap_fraction=snap_fraction)
        V, F = part.V, part.F
        parts.append(part)
    c = combined_correspondence(parts, [len(p.host_curve.indices) for p in pairs])
    check_guest_reaches_seam(c.F, len(c.V), c.seam)
    return parts, c
