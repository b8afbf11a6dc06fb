"""Boundary loops and the selection of the curve to join (paper §3).

A curve is chosen by one of

* an ordered array of boundary vertex indices,
* ``start`` and ``end`` vertices of an open curve (the boundary path between
  them; ``via`` picks the side, otherwise the shorter side is taken),
* a ``start`` vertex on a loop, or a ``loop`` index (closed curve),
* nothing, when the mesh has exactly one boundary loop.

Anywhere a vertex is taken, a 3D point is accepted and snapped to the nearest
boundary vertex.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from .errors import CurveError
from .mesh import Mesh
from .polyline import arc_length_parameters, polyline_length

__all__ = [
    "Curve",
    "SelectedCurve",
    "boundary_loops",
    "select_curve",
    "polyline_length",
    "arc_length_parameters",
    "SNAP_DISTANCE",
]

#: A point given for a vertex is snapped to the nearest boundary vertex only if
#: it lies within this many mean boundary edge lengths of it.
SNAP_DISTANCE = 5.0


@dataclass(frozen=True)
class Curve:
    """How to pick a boundary curve of a mesh.

    Parameters
    ----------
    indices : array_like of int, shape (k,), optional
        Ordered boundary vertex indices. A complete loop is a closed curve
        (unless ``closed=False``), a contiguous part of a loop an open one.
    start, end : int or array_like, shape (3,), optional
        Start and end vertex (or points snapped to the nearest boundary
        vertex). ``start`` alone picks the start of a closed curve; ``start``
        and ``end`` pick the open boundary path between them.
    via : int or array_like, shape (3,), optional
        A vertex on the wanted side of an open curve between ``start`` and
        ``end``; without it the shorter side is taken.
    loop : int, optional
        Index of the boundary loop (as listed by :func:`boundary_loops`).
    closed : bool, optional
        Force the curve kind for ``indices``.
    """

    indices: Any = None
    start: Any = None
    end: Any = None
    via: Any = None
    loop: int | None = None
    closed: bool | None = None

    @classmethod
    def coerce(cls, spec: Any, name: str) -> Curve:
        """Turn ``None``, a :class:`Curve`, a mapping or an index array into a :class:`Curve`."""
        if spec is None:
            return cls()
        if isinstance(spec, Curve):
            return spec
        if isinstance(spec, Mapping):
            unknown = set(spec) - {"indices", "start", "end", "via", "loop", "closed"}
            if unknown:
                raise CurveError(
                    f"{name}: unknown curve keys {sorted(unknown)}; use indices, start, end, "
                    "via, loop or closed"
                )
            return cls(**spec)
        if isinstance(spec, (int, np.integer)) and not isinstance(spec, bool):
            return cls(loop=int(spec))
        return cls(indices=spec)


@dataclass(frozen=True)
class SelectedCurve:
    """A boundary curve of a mesh, resolved to vertex indices.

    Attributes
    ----------
    indices : ndarray of int64, shape (k,)
        Ordered vertex indices (for a closed curve the first vertex is not repeated).
    closed : bool
        Whether the curve is a whole loop.
    loop : int
        Index of the loop the curve lies on.
    forward : bool
        True if the order follows the face-induced direction of the loop.
    """

    indices: np.ndarray
    closed: bool
    loop: int
    forward: bool

    def reversed(self) -> SelectedCurve:
        """The same curve traversed the other way (a closed curve keeps its start)."""
        if self.closed:
            idx = np.concatenate([self.indices[:1], self.indices[:0:-1]])
        else:
            idx = self.indices[::-1]
        return SelectedCurve(np.ascontiguousarray(idx), self.closed, self.loop, not self.forward)

    def rolled(self, k: int) -> SelectedCurve:
        """A closed curve started at its ``k``-th vertex."""
        return SelectedCurve(np.roll(self.indices, -k), self.closed, self.loop, self.forward)


def boundary_loops(F: np.ndarray) -> list[np.ndarray]:
    """All boundary loops, each ordered along the face-induced direction.

    Parameters
    ----------
    F : ndarray of int64, shape (m, 3)

    Returns
    -------
    list of ndarray of int64, shape (k_i,)
        Longest loop first; loops of equal length keep libigl's order.
    """
    loops = _traced_loops(F)
    if loops is None:
        import igl  # only for what the tracer leaves (libigl costs start-up time)

        loops = [np.asarray(lp, dtype=np.int64) for lp in igl.boundary_loop_all(F) if len(lp) > 0]
    loops.sort(key=len, reverse=True)
    return loops


def _traced_loops(F: np.ndarray) -> list[np.ndarray] | None:
    """Boundary loops as ``igl.boundary_loop_all`` lists them, found without a vertex loop.

    A boundary half-edge is a face edge ``F[f, i] -> F[f, (i + 1) % 3]`` whose
    undirected edge belongs to no other face. When every boundary vertex
    starts exactly one and ends exactly one boundary half-edge, the loops are
    the cycles of the map from each boundary vertex to the end of its
    half-edge; libigl then lists each cycle from its smallest vertex, cycles
    in increasing order of that vertex, which is the order returned here.

    Parameters
    ----------
    F : ndarray of int, shape (m, 3)

    Returns
    -------
    list of ndarray of int64, shape (k_i,), or None
        The loops in libigl's order, or ``None`` when the faces are not a
        plain triangle array, a face repeats a vertex or a boundary vertex
        starts or ends more than one boundary half-edge (libigl's choice then
        depends on its face order, so the caller asks libigl).

    Notes
    -----
    Kept instead of ``igl.boundary_loop_all`` for its speed, measured on the
    arguments the joins pass (three calls per join; medians on this
    machine): 0.30 / 0.96-1.28 / 4.1 ms in all against 1.5 / 3.1-3.7 / 11.4 ms
    with libigl at half, full and twice the paper resolution, i.e. +1.2 ms
    of a 31 ms join (4.0 %), +2.1 to +2.4 ms of a 176-189 ms paper join
    (1.2-1.3 %), +7 ms of a 2.55 s join (0.3 %). In joins run two at a time
    on two busy cores libigl's call took 1.2-15 ms each and paper joins were
    about 9 % slower with it (median of 84 paired joins).
    """
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3 or F.size == 0 or not np.issubdtype(F.dtype, np.integer):
        return None
    F = F.astype(np.int64, copy=False)
    if F.min() < 0:
        return None
    if ((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])).any():
        return None
    n = int(F.max()) + 1
    src = F.reshape(-1)
    dst = F[:, [1, 2, 0]].reshape(-1)
    key = np.minimum(src, dst) * n + np.maximum(src, dst)
    order = np.argsort(key, kind="stable")
    skey = key[order]
    alone = np.ones(key.size, dtype=bool)
    repeat = skey[1:] == skey[:-1]
    alone[1:] &= ~repeat
    alone[:-1] &= ~repeat
    half = order[alone]
    if half.size == 0:
        return []
    tail, head = src[half], dst[half]
    vertex = np.sort(tail)
    if (vertex[1:] == vertex[:-1]).any() or not np.array_equal(vertex, np.sort(head)):
        return None
    # local ids follow vertex order, so a cycle's smallest vertex has its smallest id
    succ = np.empty(vertex.size, dtype=np.int64)
    succ[np.searchsorted(vertex, tail)] = np.searchsorted(vertex, head)
    rounds = max(int(vertex.size - 1).bit_length(), 1)
    # pointer doubling: after r rounds ``low`` is the smallest id within 2**r steps
    low = np.arange(vertex.size)
    jump = succ
    for _ in range(rounds):
        low = np.minimum(low, low[jump])
        jump = jump[jump]
    # steps from each vertex to the last vertex of its cycle (the one before its start)
    last = succ == low
    steps = np.where(last, 0, 1)
    jump = np.where(last, np.arange(vertex.size), succ)
    for _ in range(rounds):
        steps = steps + steps[jump]
        jump = jump[jump]
    position = steps[low] - steps
    ordered = np.lexsort((position, low))
    cut = np.flatnonzero(np.diff(low[ordered])) + 1
    return [vertex[part] for part in np.split(ordered, cut)]


class _LoopIndex:
    """Which loop and which position each boundary vertex has."""

    def __init__(self, mesh: Mesh, loops: list[np.ndarray]):
        self.mesh = mesh
        self.loops = loops
        n = mesh.n_vertices
        self.loop_of = np.full(n, -1, dtype=np.int64)
        self.pos_of = np.full(n, -1, dtype=np.int64)
        for k, lp in enumerate(loops):
            self.loop_of[lp] = k
            self.pos_of[lp] = np.arange(len(lp))
        self.boundary = np.flatnonzero(self.loop_of >= 0)

    @cached_property
    def mean_edge(self) -> float:
        """Mean boundary edge length (0 without a boundary), made when a point is snapped."""
        if not self.boundary.size:
            return 0.0
        V = self.mesh.V
        edge = [np.linalg.norm(V[lp] - V[np.roll(lp, -1)], axis=1) for lp in self.loops]
        return float(np.mean(np.concatenate(edge)))

    def vertex(self, spec: Any, what: str) -> int:
        """Resolve a vertex index or a 3D point to a boundary vertex index."""
        arr = np.asarray(spec)
        if arr.shape == (3,) and np.issubdtype(arr.dtype, np.number):
            return self._snap(arr.astype(np.float64), what)
        if arr.ndim != 0 or not np.issubdtype(arr.dtype, np.integer):
            raise CurveError(
                f"{what}: expected a vertex index or a 3D point (x, y, z), got {spec!r}"
            )
        v = int(arr)
        n = self.mesh.n_vertices
        if not 0 <= v < n:
            raise CurveError(f"{what}: vertex {v} is out of range; the mesh has {n} vertices")
        if self.loop_of[v] < 0:
            raise CurveError(
                f"{what}: vertex {v} is not on a boundary of {self.mesh.name}; pick a vertex of "
                "one of its boundary loops (see igljoin.boundary_loops) or pass a 3D point to snap"
            )
        return v

    def _snap(self, p: np.ndarray, what: str) -> int:
        if not np.isfinite(p).all():
            raise CurveError(f"{what}: the point {p.tolist()} is not finite")
        with np.errstate(over="ignore"):  # overflow to inf is handled below
            d = np.linalg.norm(self.mesh.V[self.boundary] - p, axis=1)
        k = int(np.argmin(d))
        limit = SNAP_DISTANCE * self.mean_edge
        if not np.isfinite(d[k]):  # |p| near 1e308: the difference overflows
            raise CurveError(
                f"{what}: the point {p.tolist()} is too far out to measure (its distance to "
                f"{self.mesh.name} overflows float64); give a point on the boundary to join"
            )
        if d[k] > limit:
            raise CurveError(
                f"{what}: the point {np.round(p, 6).tolist()} is {d[k]:.4g} from the nearest "
                f"boundary vertex of {self.mesh.name}, farther than {SNAP_DISTANCE:g} mean "
                f"boundary edges ({limit:.4g}); give a point on the boundary to join"
            )
        return int(self.boundary[k])


def select_curve(mesh: Mesh, spec: Any, *, name: str = "curve") -> SelectedCurve:
    """Resolve a curve specification on ``mesh``.

    Parameters
    ----------
    mesh : Mesh
    spec : None, Curve, mapping, int (loop index) or array_like of int
        See :class:`Curve`.
    name : str
        Argument name for error messages.

    Returns
    -------
    SelectedCurve
        Closed curves follow the face-induced direction from their start;
        open curves run from ``start`` to ``end`` (or in the given order).

    Raises
    ------
    CurveError
        If the selection is not on a boundary, spans two loops, is too short...
    """
    curve = Curve.coerce(spec, name)
    if curve.indices is not None and any(
        v is not None for v in (curve.start, curve.end, curve.via, curve.loop)
    ):
        raise CurveError(f"{name}: give either the curve's indices or start/end/via/loop, not both")
    if curve.loop is not None and (
        isinstance(curve.loop, bool) or not isinstance(curve.loop, (int, np.integer))
    ):
        raise CurveError(f"{name}: loop={curve.loop!r} must be an integer loop index")
    loops = boundary_loops(mesh.F)
    if not loops:
        raise CurveError(
            f"{name}: {mesh.name} has no boundary loop (it is closed); cut an opening "
            "first — only a boundary curve can be joined"
        )
    index = _LoopIndex(mesh, loops)
    if curve.indices is not None:
        return _from_indices(index, curve, name)
    if curve.loop is not None:
        if not 0 <= int(curve.loop) < len(loops):
            raise CurveError(
                f"{name}: loop {curve.loop} does not exist; {mesh.name} has {len(loops)} "
                f"boundary loops (0..{len(loops) - 1}, longest first)"
            )
    if curve.start is None:
        if curve.end is not None or curve.via is not None:
            raise CurveError(f"{name}: 'end' and 'via' need a 'start' vertex as well")
        if curve.loop is None and len(loops) != 1:
            sizes = [len(lp) for lp in loops]
            shown = str(sizes)
            if len(sizes) > 10:  # bounded: a scan may have tens of thousands of tiny holes
                hint = "; close small holes with igljoin clean --close-holes"
                shown = f"{str(sizes[:10])[:-1]}, ... and {len(sizes) - 10:,} more]{hint}"
            raise CurveError(
                f"{name}: {mesh.name} has {len(loops):,} boundary loops (sizes {shown}); say which "
                "to join with a loop index, a start vertex or the curve's vertex indices"
            )
        k = 0 if curve.loop is None else int(curve.loop)
        return SelectedCurve(loops[k].copy(), True, k, True)
    start = index.vertex(curve.start, f"{name}.start")
    k = int(index.loop_of[start])
    if curve.loop is not None and k != int(curve.loop):
        raise CurveError(f"{name}: start vertex {start} is on loop {k}, not on loop {curve.loop}")
    loop = loops[k]
    if curve.end is None:
        if curve.via is not None:
            raise CurveError(
                f"{name}: 'via' needs an 'end' vertex (it picks a side of an open curve)"
            )
        return SelectedCurve(np.roll(loop, -int(index.pos_of[start])), True, k, True)
    end = index.vertex(curve.end, f"{name}.end")
    if index.loop_of[end] != k:
        raise CurveError(
            f"{name}: start vertex {start} is on boundary loop {k} but end vertex {end} is on "
            f"loop {int(index.loop_of[end])}; an open curve must lie on one loop"
        )
    if end == start:
        raise CurveError(
            f"{name}: start and end are the same vertex {start}; for a closed curve give only "
            "'start', for an open one two different vertices"
        )
    rolled = np.roll(loop, -int(index.pos_of[start]))
    j = int(np.flatnonzero(rolled == end)[0])
    forward = rolled[: j + 1]
    backward = np.concatenate([rolled[:1], rolled[: j - 1 : -1]])
    if curve.via is not None:
        via = index.vertex(curve.via, f"{name}.via")
        if index.loop_of[via] != k:
            raise CurveError(
                f"{name}: via vertex {via} is not on the loop of start and end (loop {k}); "
                "give a vertex of that loop"
            )
        if via in (start, end):
            raise CurveError(f"{name}: via vertex {via} must differ from start and end")
        use_forward = bool(np.isin(via, forward))
    else:
        V = mesh.V
        use_forward = polyline_length(V[forward], False) <= polyline_length(V[backward], False)
    idx = forward if use_forward else backward
    return _checked_open(mesh, SelectedCurve(idx.copy(), False, k, use_forward), name)


def _checked_open(mesh: Mesh, c: SelectedCurve, name: str) -> SelectedCurve:
    if len(c.indices) < 3:
        raise CurveError(
            f"{name}: the open curve {c.indices.tolist()} has a single edge; an open curve "
            "needs at least two edges (three vertices) to be joined"
        )
    return c


def _from_indices(index: _LoopIndex, curve: Curve, name: str) -> SelectedCurve:
    try:
        idx = np.asarray(curve.indices)
    except (TypeError, ValueError):
        idx = np.asarray([], dtype=object)
    if idx.ndim != 1 or idx.size == 0 or not np.issubdtype(idx.dtype, np.integer):
        raise CurveError(
            f"{name}: curve indices must be a non-empty 1-D array of vertex indices, "
            f"got {curve.indices!r}"
        )
    idx = idx.astype(np.int64)
    n = index.mesh.n_vertices
    if idx.min() < 0 or idx.max() >= n:
        raise CurveError(
            f"{name}: curve indices range over [{idx.min()}, {idx.max()}] but the mesh has {n} "
            "vertices"
        )
    off = idx[index.loop_of[idx] < 0]
    if off.size:
        raise CurveError(
            f"{name}: vertices {off[:5].tolist()} are not on a boundary of {index.mesh.name}; "
            "curve indices must be boundary vertices (see igljoin.boundary_loops)"
        )
    ks = np.unique(index.loop_of[idx])
    if ks.size != 1:
        raise CurveError(
            f"{name}: the curve's vertices lie on {ks.size} different boundary loops "
            f"({ks.tolist()}); a curve must lie on one loop"
        )
    if np.unique(idx).size != idx.size:
        raise CurveError(f"{name}: curve indices repeat a vertex; list each vertex once")
    k = int(ks[0])
    loop = index.loops[k]
    m = len(loop)
    pos = index.pos_of[idx]
    step = np.diff(pos) % m
    if idx.size > 1 and (step == 1).all():
        forward = True
    elif idx.size > 1 and (step == m - 1).all():
        forward = False
    else:
        raise CurveError(
            f"{name}: the curve indices are not consecutive along boundary loop {k}; list them "
            "in order along the boundary"
        )
    whole = idx.size == m
    closed = whole if curve.closed is None else bool(curve.closed)
    if closed and not whole:
        raise CurveError(
            f"{name}: closed=True but the indices cover {idx.size} of the loop's {m} vertices; "
            "give the whole loop or set closed=False"
        )
    sel = SelectedCurve(idx.copy(), closed, k, forward)
    return sel if closed else _checked_open(index.mesh, sel, name)
