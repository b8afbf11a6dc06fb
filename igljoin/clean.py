"""Mesh diagnosis, repair and resampling (repair and resampling use pymeshlab).

Three functions:

* :func:`diagnose` lists what is wrong with a mesh: degenerate, zero-area,
  sliver and duplicate faces, non-manifold edges and vertices, unreferenced
  and duplicate vertices, components and boundary loops. Plain numpy/scipy;
  it never needs pymeshlab.
* :func:`clean` repairs those problems with pymeshlab filters and reports how
  many elements each fix touched (:class:`CleanReport`). Vertex positions are
  never moved, so a curve given by points still selects the same place, and
  :meth:`CleanReport.remap_curve` carries curves given by vertex indices over
  to the cleaned mesh.
* :func:`resample` remeshes a surface to a target edge length while keeping
  every boundary polyline exactly where it was (:class:`ResampleReport`).

pymeshlab is imported only inside :func:`clean` and :func:`resample`; without
it they raise :class:`~igljoin.errors.MissingExtraError` naming the extra to
install (``pip install 'igljoin[meshlab]'``).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import topology
from .boundary import Curve, boundary_loops, polyline_length, select_curve
from .errors import CurveError, MeshError, missing_extra
from .frames import face_areas
from .mesh import Mesh, as_mesh
from .validate import relative_area_floor

__all__ = [
    "MAX_HOLE_EDGES",
    "MIN_COMPONENT_FACES",
    "RESAMPLE_ITERATIONS",
    "SLIVER_RATIO",
    "CleanReport",
    "ResampleReport",
    "clean",
    "clean_setting_problem",
    "diagnose",
    "resample",
    "resample_setting_problem",
]

#: Faces whose aspect ratio ``2 r / R`` (inradius over circumradius, 1 for an
#: equilateral triangle) is below this value count as slivers. Real scans hold
#: a few faces around 1e-2 that join fine; 1e-3 only catches near-degenerate ones.
SLIVER_RATIO = 1e-3

#: Default of :func:`clean`'s ``max_hole_edges``: holes of up to 30 boundary
#: edges are scan drop-outs; larger ones are openings of the anatomy.
MAX_HOLE_EDGES = 30
#: Default of :func:`clean`'s ``min_component_faces``: loose pieces smaller than
#: this are scan debris.
MIN_COMPONENT_FACES = 10
#: Default of :func:`resample`'s ``iterations`` (enough for an even mesh).
RESAMPLE_ITERATIONS = 10
#: Largest value a pymeshlab integer parameter takes (a C++ ``int``).
_C_INT_MAX = 2**31 - 1
#: Most remeshing iterations :func:`resample` runs (each one passes over every face).
MAX_RESAMPLE_ITERATIONS = 100


def _is_integer(value: Any, low: int, high: int) -> bool:
    return (
        not isinstance(value, bool)
        and isinstance(value, (int, np.integer))
        and low <= value <= high
    )


def clean_setting_problem(
    max_hole_edges: Any, sliver_ratio: Any, min_component_faces: Any
) -> tuple[str, Any, str] | None:
    """The first out-of-range setting of :func:`clean`, or ``None`` if all are valid.

    The one rule for these settings, shared by :func:`clean` and
    :class:`igljoin.spec.CleanupSpec` (each words the error its own way).

    Returns
    -------
    (name, value, requirement) or None
        ``requirement`` completes "``name`` = ``value`` ...", e.g. "must be a
        number in [0, 1)".
    """
    for name, value, low in (
        ("max_hole_edges", max_hole_edges, 3),
        ("min_component_faces", min_component_faces, 0),
    ):
        if not _is_integer(value, low, _C_INT_MAX):
            return name, value, f"must be an integer from {low} to {_C_INT_MAX:,}"
    if isinstance(sliver_ratio, bool) or not (
        isinstance(sliver_ratio, (int, float, np.integer, np.floating)) and 0 <= sliver_ratio < 1
    ):
        return "sliver_ratio", sliver_ratio, "must be a number in [0, 1)"
    return None


def resample_setting_problem(target_edge: Any, iterations: Any) -> tuple[str, Any, str] | None:
    """The first out-of-range setting of :func:`resample`, or ``None`` if both are valid.

    Shared by :func:`resample` and :class:`igljoin.spec.ResampleSpec`; see
    :func:`clean_setting_problem`.
    """
    try:
        target = float(target_edge)
    except (TypeError, ValueError, OverflowError):  # 10**400, a complex number
        target = float("nan")
    number = isinstance(target_edge, numbers.Real) and not isinstance(target_edge, bool)
    if not (number and math.isfinite(target) and target > 0):
        return "target_edge", target_edge, "must be a positive length"
    if not _is_integer(iterations, 1, MAX_RESAMPLE_ITERATIONS):
        return (
            "iterations",
            iterations,
            f"must be an integer from 1 to {MAX_RESAMPLE_ITERATIONS} (the default "
            f"{RESAMPLE_ITERATIONS} is enough for an even mesh)",
        )
    return None


#: Fixes reported by :func:`clean`, in the order they are applied.
FIXES = (
    "unreferenced_vertices",
    "duplicate_vertices",
    "duplicate_faces",
    "zero_area_faces",
    "non_manifold_edge_faces",
    "non_manifold_vertices",
    "faces_reoriented",
    "sliver_faces_flipped",
    "sliver_faces_removed",
    "small_component_faces",
    "holes_closed",
    "touching_vertices_separated",
)

#: Problems counted by :func:`diagnose` (each is 0 for a mesh ready to join).
PROBLEMS = (
    "degenerate_faces",
    "zero_area_faces",
    "sliver_faces",
    "duplicate_faces",
    "non_manifold_edges",
    "non_manifold_vertices",
    "inconsistent_orientation",
    "unreferenced_vertices",
    "duplicate_vertices",
)


# --------------------------------------------------------------------------- diagnosis


def _edge_lengths(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Lengths (m, 3) of the edges opposite each corner."""
    return np.stack(
        [
            np.linalg.norm(V[F[:, 1]] - V[F[:, 2]], axis=1),
            np.linalg.norm(V[F[:, 2]] - V[F[:, 0]], axis=1),
            np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1),
        ],
        axis=1,
    )


def aspect_ratios(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Aspect ratio ``2 r / R`` (m,) of each face ``F`` (m, 3) of ``V`` (n, 3).

    1 for equilateral, 0 for degenerate: ``16 A^2 / (a b c (a + b + c))``
    with ``A`` the area and ``a, b, c`` the edge lengths, the measure
    pymeshlab's ``compute_selection_bad_faces`` uses.
    """
    L = _edge_lengths(V, F)
    area = face_areas(V, F)
    denom = L.prod(axis=1) * L.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.where(denom > 0, 16.0 * area**2 / np.where(denom > 0, denom, 1.0), 0.0)
    return q


def diagnose(mesh: Any, *, sliver_ratio: float = SLIVER_RATIO) -> dict:
    """List the problems of a mesh that stop it from being joined.

    Parameters
    ----------
    mesh : Mesh or (V, F)
        Any structurally valid mesh (see :class:`igljoin.Mesh`); it may be
        non-manifold or hold degenerate faces.
    sliver_ratio : float, optional
        Faces with aspect ratio ``2 r / R`` below this are slivers.

    Returns
    -------
    dict
        Plain JSON. ``vertices``, ``faces``, ``mean_edge``, ``bbox_diagonal``;
        ``problems``: counts of ``degenerate_faces`` (a repeated vertex),
        ``zero_area_faces`` (distinct vertices, area below ``1e-12`` of the
        mean face area, as :func:`igljoin.join` checks), ``sliver_faces``
        (other faces thinner than ``sliver_ratio``), ``duplicate_faces``
        (faces beyond the first with the same three vertices),
        ``non_manifold_edges`` (edges of more than two faces),
        ``non_manifold_vertices`` (vertices whose faces form several fans),
        ``inconsistent_orientation`` (directed edges that two faces traverse
        the same way, i.e. neighbours with opposite orientations),
        ``unreferenced_vertices`` and ``duplicate_vertices`` (referenced
        vertices at exactly the same position as another);
        ``components`` (count) and ``component_faces`` (face counts, largest
        first, at most 20); ``boundary_edges`` and ``loops`` (a list of
        ``{"size", "length"}``, longest first, as
        :func:`igljoin.boundary_loops` orders them) — ``loops`` is ``None``
        while the mesh has non-manifold edges, because loops are then not
        well defined; ``ok``: whether every problem count is 0.

    Examples
    --------
    >>> import igljoin
    >>> s = igljoin.phantoms.paper_sample("partial_patch", "equal", resolution=0.4)
    >>> info = diagnose(s.guest)
    >>> info["ok"], len(info["loops"])
    (True, 1)
    """
    m = as_mesh(mesh)
    V, F = m.V, m.F
    n = m.n_vertices
    degenerate = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    area2 = 2.0 * face_areas(V, F)
    floor = relative_area_floor * max(float(area2.mean()), 1e-300)
    zero = ~degenerate & (area2 <= floor)
    sliver = ~degenerate & ~zero & (aspect_ratios(V, F) < sliver_ratio)
    good = ~degenerate
    unique_faces, first, dup_count = np.unique(
        np.sort(F[good], axis=1), axis=0, return_index=True, return_counts=True
    )
    edges, _, edge_faces = topology.edges(unique_faces, n)
    used = np.zeros(n, dtype=bool)
    used[F.reshape(-1)] = True
    fans = topology.fan_counts(unique_faces, n)
    _, comp_sizes = topology.components(F, n)
    comp_sizes = np.sort(comp_sizes)[::-1]
    lengths = np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1) if len(edges) else []
    problems = {
        "degenerate_faces": int(degenerate.sum()),
        "zero_area_faces": int(zero.sum()),
        "sliver_faces": int(sliver.sum()),
        "duplicate_faces": int((dup_count - 1).sum()),
        "non_manifold_edges": int((edge_faces > 2).sum()),
        "non_manifold_vertices": int((fans > 1).sum()),
        "inconsistent_orientation": topology.repeated_directed_edges(F[good][first], n),
        "unreferenced_vertices": int((~used).sum()),
        "duplicate_vertices": topology.repeated_rows(V[used]),
    }
    loops = None
    if problems["non_manifold_edges"] == 0 and good.any():
        # a closed surface has no loops: libigl (and its start-up time) is not needed then
        open_edges = (edge_faces == 1).any()
        loops = [
            {"size": int(len(lp)), "length": polyline_length(V[lp], True)}
            for lp in (boundary_loops(F[good]) if open_edges else [])
        ]
    diag = float(np.linalg.norm(np.ptp(V[used], axis=0))) if used.any() else 0.0
    return {
        "vertices": n,
        "faces": m.n_faces,
        "mean_edge": float(np.mean(lengths)) if len(lengths) else 0.0,
        "bbox_diagonal": diag,
        "problems": problems,
        "components": int(len(comp_sizes)),
        "component_faces": [int(s) for s in comp_sizes[:20]],
        "boundary_edges": int((edge_faces == 1).sum()),
        "loops": loops,
        "ok": not any(problems.values()),
    }


# --------------------------------------------------------------------------- pymeshlab bridge


def _pymeshlab(feature: str):
    try:
        import pymeshlab
    except ImportError:
        raise missing_extra("pymeshlab", "meshlab", feature) from None
    return pymeshlab


def _meshset(ml, V: np.ndarray, F: np.ndarray, source: np.ndarray, face_flag=None):
    """A MeshSet holding (V, F); vertex quality carries ``source``, face quality ``face_flag``."""
    kwargs = {"v_scalar_array": np.ascontiguousarray(source, dtype=np.float64)}
    if face_flag is not None:
        kwargs["f_scalar_array"] = np.ascontiguousarray(face_flag, dtype=np.float64)
    ms = ml.MeshSet()
    ms.add_mesh(
        ml.Mesh(
            np.ascontiguousarray(V, dtype=np.float64),
            np.ascontiguousarray(F, dtype=np.int32),
            **kwargs,
        )
    )
    return ms


def _arrays(ms) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(V float64, F int64, vertex quality as int64 source ids) of the current mesh."""
    cm = ms.current_mesh()
    V = np.array(cm.vertex_matrix(), dtype=np.float64)
    F = np.array(cm.face_matrix(), dtype=np.int64)  # pymeshlab gives int32
    q = np.asarray(cm.vertex_scalar_array(), dtype=np.float64)
    source = np.where(np.isfinite(q) & (q >= 0), np.rint(q), -1).astype(np.int64)
    return V, F.reshape(-1, 3), source


def _select_faces(ml, V, F, source, mask):
    """A MeshSet whose face selection is ``mask``."""
    ms = _meshset(ml, V, F, source, face_flag=mask.astype(np.float64))
    ms.compute_selection_by_condition_per_face(condselect="fq > 0.5")
    return ms


# --------------------------------------------------------------------------- clean


@dataclass(frozen=True)
class CleanReport:
    """What :func:`clean` changed.

    Attributes
    ----------
    fixes : dict of str to int
        Elements touched by each fix, in the order applied:
        ``unreferenced_vertices`` (removed), ``duplicate_vertices`` (merged
        into an identical one), ``duplicate_faces`` (removed),
        ``zero_area_faces`` (removed; includes faces repeating a vertex),
        ``sliver_faces_flipped`` (slivers repaired by flipping their long
        edge), ``sliver_faces_removed`` (slivers that could not be flipped,
        e.g. on the boundary), ``non_manifold_edge_faces`` (faces removed so
        that every edge has at most two faces), ``non_manifold_vertices``
        (vertices split so that each has one fan), ``small_component_faces``
        (faces of small loose pieces removed), ``holes_closed`` (boundary
        loops filled) and ``touching_vertices_separated`` (copies of a
        position on separate sheets moved :data:`TOUCH_SEPARATION` mean
        edges apart, see :func:`_separate_touching`).
    before, after : dict
        :func:`diagnose` of the input and of the output.
    source : ndarray of int64, shape (n_out,)
        Input vertex of each output vertex (-1 for none). Vertex positions are
        never changed, so ``out.V[i] == mesh.V[source[i]]``.
    to_output : ndarray of int64, shape (n_in,)
        Output vertex at the position of each input vertex (-1 if it was
        removed). Merged duplicates map to the vertex they were merged into.
    kept_loop : int or None
        Index (in the cleaned mesh, before holes were closed) of the boundary
        loop that ``keep_boundary`` protected.
    """

    fixes: dict
    before: dict
    after: dict
    source: np.ndarray = field(repr=False)
    to_output: np.ndarray = field(repr=False)
    kept_loop: int | None = None

    @property
    def total(self) -> int:
        """Total number of elements touched by all fixes."""
        return int(sum(self.fixes.values()))

    def remap_vertex(self, v: int, what: str = "vertex") -> int:
        """Output index of input vertex ``v``; :class:`CurveError` if it was removed."""
        n = len(self.to_output)
        if not 0 <= int(v) < n:
            raise CurveError(f"{what}: vertex {v} is out of range; the input mesh has {n} vertices")
        out = int(self.to_output[int(v)])
        if out < 0:
            raise CurveError(
                f"{what}: vertex {v} was removed by cleanup (it was unreferenced or only used by "
                "removed faces); pick another vertex or give the curve by points [x, y, z]"
            )
        return out

    def remap_curve(self, spec: Any, name: str = "curve") -> Curve:
        """Carry a curve specification of the input mesh over to the cleaned mesh.

        Vertex indices (``indices``, integer ``start``/``end``/``via``) are
        mapped through :attr:`to_output`; points and loop indices are kept
        (loop indices refer to the mesh being joined, i.e. the cleaned one).

        Parameters
        ----------
        spec : None, Curve, mapping, int or array_like
            See :class:`igljoin.Curve`.
        name : str
            Used in error messages.

        Returns
        -------
        Curve
        """
        c = Curve.coerce(spec, name)

        def one(v, key):
            if v is None:
                return None
            a = np.asarray(v)
            if a.ndim == 0 and np.issubdtype(a.dtype, np.integer):
                return self.remap_vertex(int(a), f"{name}.{key}")
            return v

        indices = c.indices
        if indices is not None:
            idx = np.asarray(indices)
            if idx.ndim == 1 and np.issubdtype(idx.dtype, np.integer):
                indices = np.array([self.remap_vertex(int(i), f"{name}.indices") for i in idx])
        return Curve(
            indices=indices,
            start=one(c.start, "start"),
            end=one(c.end, "end"),
            via=one(c.via, "via"),
            loop=c.loop,
            closed=c.closed,
        )

    def to_json(self) -> dict:
        """Plain-JSON form (without the per-vertex maps)."""
        return {
            "fixes": {k: int(v) for k, v in self.fixes.items()},
            "total": self.total,
            "kept_loop": self.kept_loop,
            "before": self.before,
            "after": self.after,
        }


def _to_output_map(V_in: np.ndarray, V_out: np.ndarray, source: np.ndarray) -> np.ndarray:
    """Input vertex -> output vertex, by source id, then by identical position."""
    n = len(V_in)
    out = np.full(n, -1, dtype=np.int64)
    ok = (source >= 0) & (source < n)
    idx = np.flatnonzero(ok)
    out[source[idx[::-1]]] = idx[::-1]  # the first output vertex of each source wins
    missing = np.flatnonzero(out < 0)
    if missing.size and len(V_out):
        lookup: dict[bytes, int] = {}
        for i in range(len(V_out) - 1, -1, -1):
            lookup[V_out[i].tobytes()] = i
        for v in missing:
            out[v] = lookup.get(V_in[v].tobytes(), -1)
    return out


def _unit_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _manifold_edges(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, int]:
    """Remove faces until no edge has more than two faces; return (F, faces removed).

    At an edge with more than two faces the pair kept is the one that is
    consistently oriented across the edge and flattest (largest normal dot
    product); the others (fins, flaps, stacked sheets) are removed.
    pymeshlab's ``meshing_repair_non_manifold_edges`` removes the smallest
    faces instead, which cuts holes in the real surface next to a large fin.
    """
    if not len(F):
        return F, 0
    edges, inverse, counts = topology.edges(F)
    bad = np.flatnonzero(counts > 2)
    if not bad.size:
        return F, 0
    m = len(F)
    face_of = np.tile(np.arange(m), 3)
    tail = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])  # first vertex of each face edge
    order = np.argsort(inverse, kind="stable")
    starts = np.searchsorted(inverse[order], bad)
    normals = _unit_normals(V, F)
    keep = np.ones(m, dtype=bool)
    for e, start in zip(bad, starts):
        rows = order[start : start + counts[e]]
        rows = rows[keep[face_of[rows]]]
        if len(rows) <= 2:
            continue
        faces = face_of[rows]
        forward = tail[rows] == edges[e, 0]
        dots = normals[faces] @ normals[faces].T
        score = dots - 3.0 * (forward[:, None] == forward[None, :])  # prefer consistent pairs
        np.fill_diagonal(score, -np.inf)
        i, j = np.unravel_index(int(np.argmax(score)), score.shape)
        drop = np.ones(len(faces), dtype=bool)
        drop[[i, j]] = False
        keep[faces[drop]] = False
    return F[keep], int((~keep).sum())


def _orient(F: np.ndarray) -> tuple[np.ndarray, int]:
    """Orient faces consistently per component, keeping each component's majority orientation.

    Returns the new faces and the number of faces reversed.
    """
    if not len(F):
        return F, 0
    import igl  # here, not at the top: libigl costs start-up time (igljoin info)

    FF, C = igl.bfs_orient(np.ascontiguousarray(F, dtype=np.int64))
    FF = np.asarray(FF, dtype=np.int64)
    same = np.zeros(len(F), dtype=bool)
    for shift in range(3):
        same |= (np.roll(F, shift, axis=1) == FF).all(axis=1)
    flipped = ~same
    C = np.asarray(C, dtype=np.int64).reshape(-1)
    per_comp = np.bincount(C, weights=flipped.astype(float))
    size = np.bincount(C)
    majority = per_comp > 0.5 * size  # the BFS seed had the minority orientation
    flipped = flipped ^ majority[C]
    out = np.where(flipped[:, None], F[:, ::-1], F)
    return np.ascontiguousarray(out), int(flipped.sum())


def _apply(ms, counts: dict, key: str, measure: str, filter_name: str, **params) -> None:
    """Apply one pymeshlab filter and add what it changed to ``counts[key]``.

    ``measure`` is ``"removed_vertices"``, ``"removed_faces"`` or ``"added_vertices"``.
    Faces that a vertex filter removes (merging the corners of a face makes it
    degenerate) are added to ``counts["zero_area_faces"]``.
    """
    before = ms.current_mesh()
    b = (before.vertex_number(), before.face_number())
    getattr(ms, filter_name)(**params)
    after = ms.current_mesh()
    a = (after.vertex_number(), after.face_number())
    change = {
        "removed_vertices": b[0] - a[0],
        "removed_faces": b[1] - a[1],
        "added_vertices": a[0] - b[0],
    }[measure]
    counts[key] += int(change)
    if measure != "removed_faces":
        counts["zero_area_faces"] += int(b[1] - a[1])


def _split_non_manifold_vertices(ms, counts: dict) -> None:
    """pymeshlab's repair of vertices with several fans (a copy per fan, none moved)."""
    _apply(
        ms,
        counts,
        "non_manifold_vertices",
        "added_vertices",
        "meshing_repair_non_manifold_vertices",
        vertdispratio=0.0,
    )


def clean(
    mesh: Any,
    *,
    close_holes: bool = False,
    keep_boundary: Any = None,
    max_hole_edges: int = MAX_HOLE_EDGES,
    sliver_ratio: float = SLIVER_RATIO,
    min_component_faces: int = MIN_COMPONENT_FACES,
) -> tuple[Mesh, CleanReport]:
    """Repair a mesh so that it can be joined.

    Applies, in this order: remove unreferenced vertices; merge duplicate
    vertices (identical coordinates); remove duplicate faces; remove
    zero-area faces (``meshing_remove_null_faces``); remove the faces that
    make edges non-manifold (keeping the flattest consistently oriented pair
    at each edge); split non-manifold vertices; orient faces consistently
    (each component keeps its majority orientation); repair sliver faces by
    flipping their long edge (``meshing_remove_t_vertices``) and remove the
    slivers that remain (``compute_selection_bad_faces`` +
    ``meshing_remove_selected_faces``); remove loose components of fewer
    than ``min_component_faces`` faces (never the largest); remove vertices
    left unreferenced; optionally close small holes.

    Parameters
    ----------
    mesh : Mesh or (V, F)
        The mesh to repair; it is not modified.
    close_holes : bool, optional
        Fill boundary loops of at most ``max_hole_edges`` edges (except the
        one ``keep_boundary`` names) with ``meshing_close_holes``.
    keep_boundary : None, Curve, mapping, int or array_like, optional
        The boundary curve to be joined, which stays open: a curve
        specification of :class:`igljoin.Curve` in which vertex indices refer
        to the *input* mesh (they are carried over), points are snapped on the
        cleaned mesh and a loop index refers to the cleaned mesh.
    max_hole_edges : int, optional
        Largest hole (in boundary edges) that ``close_holes`` fills.
    sliver_ratio : float, optional
        Aspect-ratio threshold of a sliver (see :data:`SLIVER_RATIO`).
    min_component_faces : int, optional
        Loose components with fewer faces are removed (0 keeps all).

    Returns
    -------
    mesh : Mesh
        The repaired mesh, named like the input. Vertices are never moved
        (vertex attributes are carried over when every output vertex comes
        from an input vertex; face attributes are dropped).
    report : CleanReport
        Counts per fix, diagnoses before and after, and vertex maps.

    Raises
    ------
    MissingExtraError
        If pymeshlab is not installed.
    MeshError
        If an argument is out of range or no face is left after cleaning.
    CurveError
        If ``keep_boundary`` does not name a boundary of the cleaned mesh.

    Notes
    -----
    A split non-manifold vertex keeps its position, so a guest pinched at a
    vertex still holds two vertices at one place afterwards (the join
    refuses that); loose pieces hanging from a vertex are removed as small
    components instead.

    Examples
    --------
    >>> import numpy as np, igljoin
    >>> s = igljoin.phantoms.paper_sample("partial_patch", "equal", resolution=0.4)
    >>> V = np.vstack([s.guest.V, s.guest.V[:3]])            # 3 duplicate vertices...
    >>> F = np.vstack([s.guest.F, len(s.guest.V) + np.arange(3)])  # ...used by one face
    >>> out, rep = clean(igljoin.Mesh(V, F))
    >>> rep.fixes["duplicate_vertices"], out.n_vertices == s.guest.n_vertices
    (3, True)
    """
    m = as_mesh(mesh)
    problem = clean_setting_problem(max_hole_edges, sliver_ratio, min_component_faces)
    if problem is not None:
        name, value, requirement = problem
        raise MeshError(f"clean: {name}={_short(value)} {requirement}")
    ml = _pymeshlab("igljoin.clean (mesh repair)")
    before = diagnose(m, sliver_ratio=sliver_ratio)
    counts: dict[str, int] = {k: 0 for k in FIXES}
    F = m.F
    degenerate = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    counts["zero_area_faces"] += int(degenerate.sum())
    ms = _meshset(ml, m.V, F[~degenerate], np.arange(m.n_vertices))
    for key, measure, name in (
        ("unreferenced_vertices", "removed_vertices", "meshing_remove_unreferenced_vertices"),
        ("duplicate_vertices", "removed_vertices", "meshing_remove_duplicate_vertices"),
        ("duplicate_faces", "removed_faces", "meshing_remove_duplicate_faces"),
        ("zero_area_faces", "removed_faces", "meshing_remove_null_faces"),
    ):
        _apply(ms, counts, key, measure, name)
    V, F, source = _arrays(ms)
    F, counts["non_manifold_edge_faces"] = _manifold_edges(V, F)
    ms = _meshset(ml, V, F, source)
    _split_non_manifold_vertices(ms, counts)
    V, F, source = _arrays(ms)
    F, counts["faces_reoriented"] = _orient(F)
    slivers = aspect_ratios(V, F) < sliver_ratio
    if slivers.any():
        ms = _meshset(ml, V, F, source)
        ms.meshing_remove_t_vertices(method="Edge Flip", threshold=40.0, repeat=True)
        V, F, source = _arrays(ms)
        left = aspect_ratios(V, F) < sliver_ratio
        counts["sliver_faces_flipped"] = max(int(slivers.sum()) - int(left.sum()), 0)
        if left.any():
            ms = _meshset(ml, V, F, source)
            ms.compute_selection_bad_faces(usear=True, aratio=float(sliver_ratio))
            _apply(
                ms, counts, "sliver_faces_removed", "removed_faces", "meshing_remove_selected_faces"
            )
            # a removed face can leave a vertex with two fans
            _split_non_manifold_vertices(ms, counts)
            V, F, source = _arrays(ms)
    if not len(F):
        raise MeshError(
            f"clean: no face of {m.name} is left after removing degenerate, duplicate and "
            "non-manifold faces; the mesh holds no usable surface"
        )
    if min_component_faces > 0:
        label, sizes = topology.components(F, len(V))
        limit = min(int(min_component_faces), int(sizes.max()))
        drop = sizes[label] < limit
        counts["small_component_faces"] = int(drop.sum())
        F = F[~drop]
    used = np.zeros(len(V), dtype=bool)
    used[F.reshape(-1)] = True
    if not used.all():
        counts["unreferenced_vertices"] += int((~used).sum())
        remap = np.cumsum(used) - 1
        V, source, F = V[used], source[used], remap[F]
    to_output = _to_output_map(m.V, V, source)
    kept_loop = None
    if keep_boundary is not None:
        provisional = CleanReport(counts, before, {}, source, to_output)
        spec = provisional.remap_curve(keep_boundary, "keep_boundary")
        kept_loop = select_curve(Mesh(V, F, name=m.name), spec, name="keep_boundary").loop
    if close_holes:
        loops = boundary_loops(F)
        fill = [k for k, lp in enumerate(loops) if k != kept_loop and len(lp) <= max_hole_edges]
        if fill:
            on_hole = np.zeros(len(V), dtype=bool)
            for k in fill:
                on_hole[loops[k]] = True
            rim = on_hole[F].sum(axis=1) >= 2  # faces with an edge on a hole to fill
            ms = _select_faces(ml, V, F, source, rim)
            ms.meshing_close_holes(
                maxholesize=int(max_hole_edges),
                selected=True,
                newfaceselected=False,
                selfintersection=True,
            )
            V, F, source = _arrays(ms)
            counts["holes_closed"] = len(loops) - len(boundary_loops(F))
            to_output = _to_output_map(m.V, V, source)
    V, counts["touching_vertices_separated"] = _separate_touching(V, F)
    vattrs = {}
    if m.vertex_attributes and (source >= 0).all():
        vattrs = {k: np.asarray(v)[source] for k, v in m.vertex_attributes.items()}
    out = Mesh(V, F, vertex_attributes=vattrs, name=m.name)
    report = CleanReport(
        fixes=counts,
        before=before,
        after=diagnose(out, sliver_ratio=sliver_ratio),
        source=source,
        to_output=to_output,
        kept_loop=kept_loop,
    )
    return out, report


#: How far :func:`clean` moves a vertex off another at the same position, in mean
#: edge lengths: far above float64 rounding (1e-16), far below anything visible.
TOUCH_SEPARATION = 1e-3


def _separate_touching(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, int]:
    """Move apart vertices that share a position but belong to separate sheets.

    Two sheets of a surface that touch at a point (``cow.obj``: two closed
    fans meeting at one position) have a vertex each at that point. Merging
    them makes a non-manifold vertex and splitting that re-creates the
    duplicate, so instead every copy but the first moves
    :data:`TOUCH_SEPARATION` mean edges towards the centroid of its own
    one-ring: onto its own sheet, without flipping a face.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray, shape (m, 3)

    Returns
    -------
    V : ndarray, shape (n, 3)
        A copy with the copies moved (``V`` itself if nothing moved).
    moved : int
        How many vertices moved.
    """
    used = np.zeros(len(V), dtype=bool)
    used[F.reshape(-1)] = True
    ids = np.flatnonzero(used)
    _, inverse, counts = np.unique(V[ids], axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    shared = counts[inverse] > 1
    if not shared.any():
        return V, 0
    edges, _, _ = topology.edges(F)
    mean_edge = float(np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1).mean())
    out = V.copy()
    seen: set[int] = set()
    moved = 0
    for v, group in zip(ids[shared], inverse[shared]):
        if group not in seen:  # the first copy stays where it is
            seen.add(int(group))
            continue
        ring = np.unique(F[(F == v).any(axis=1)])
        ring = ring[ring != v]
        direction = V[ring].mean(axis=0) - V[v]
        length = float(np.linalg.norm(direction))
        if length == 0.0:
            continue  # diagnose() will still report it, naming the vertex
        out[v] = V[v] + direction * (TOUCH_SEPARATION * mean_edge / length)
        moved += 1
    return out, moved


# --------------------------------------------------------------------------- resample


@dataclass(frozen=True)
class ResampleReport:
    """What :func:`resample` did.

    Attributes
    ----------
    target_edge : float
        Requested edge length.
    subdivisions : int
        Midpoint subdivision passes used to bring long edges (including the
        boundary edges) down to at most 4/3 of the target.
    before, after : dict
        ``vertices``, ``faces``, ``mean_edge``, ``boundary_mean_edge``.
    boundary_deviation : float
        Largest distance of an output boundary vertex from the input boundary
        polylines (0 up to rounding: the boundary is only refined along its
        own straight edges).
    kept : ndarray of int64 or None
        Output vertex indices of the ``keep`` curve, in curve order (the
        input curve's vertices plus the points inserted on its edges).
    kept_closed : bool or None
        Whether the kept curve is closed.
    kept_loop : int or None
        Index of the output boundary loop holding the kept curve.
    """

    target_edge: float
    subdivisions: int
    before: dict
    after: dict
    boundary_deviation: float
    kept: np.ndarray | None = field(default=None, repr=False)
    kept_closed: bool | None = None
    kept_loop: int | None = None

    def to_json(self) -> dict:
        """Plain-JSON form (kept curve given by its length in vertices)."""
        return {
            "target_edge": float(self.target_edge),
            "subdivisions": int(self.subdivisions),
            "before": self.before,
            "after": self.after,
            "boundary_deviation": float(self.boundary_deviation),
            "kept_vertices": None if self.kept is None else int(len(self.kept)),
            "kept_loop": self.kept_loop,
        }


def _edge_stats(V: np.ndarray, F: np.ndarray) -> dict:
    edges, _, counts = topology.edges(F)
    lengths = np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1)
    border = lengths[counts == 1]
    return {
        "vertices": int(len(V)),
        "faces": int(len(F)),
        "mean_edge": float(lengths.mean()),
        "boundary_mean_edge": float(border.mean()) if border.size else 0.0,
    }


def _segment_distance(P: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Distance of each point P (p, 3) to the nearest segment A[j]-B[j] (s, 3)."""
    out = np.full(len(P), np.inf)
    D = B - A
    dd = np.maximum(np.einsum("ij,ij->i", D, D), 1e-300)
    for start in range(0, len(P), 256):
        Q = P[start : start + 256]
        t = np.clip(np.einsum("pij,ij->pi", Q[:, None, :] - A[None], D) / dd, 0.0, 1.0)
        C = A[None] + t[..., None] * D[None]
        out[start : start + 256] = np.linalg.norm(Q[:, None, :] - C, axis=2).min(axis=1)
    return out


def _boundary_segments(V: np.ndarray, loops: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    A = np.concatenate([V[lp] for lp in loops])
    B = np.concatenate([V[np.roll(lp, -1)] for lp in loops])
    return A, B


def _kept_curve(
    mesh: Mesh, keep: Any, V: np.ndarray, loops: list[np.ndarray]
) -> tuple[np.ndarray, bool, int]:
    """The ``keep`` curve of ``mesh`` followed along the output boundary loops."""
    sel = select_curve(mesh, keep, name="keep")
    lookup = {}
    for k, lp in enumerate(loops):
        for pos, v in enumerate(lp):
            lookup[V[v].tobytes()] = (k, pos)
    hits = [lookup.get(mesh.V[v].tobytes()) for v in sel.indices]
    if any(h is None for h in hits) or len({h[0] for h in hits}) != 1:
        raise MeshError(
            "resample: the kept curve's vertices are no longer on one boundary loop of the "
            "output; the boundary was not preserved (please report this)"
        )
    k = hits[0][0]
    loop = loops[k]
    rolled = np.roll(loop, -hits[0][1])
    if not sel.forward:
        rolled = np.concatenate([rolled[:1], rolled[:0:-1]])
    if sel.closed:
        return rolled, True, k
    end = int(np.flatnonzero(rolled == loop[hits[-1][1]])[0])
    return rolled[: end + 1].copy(), False, k


#: Most faces :func:`resample` may produce, predicted from the area before any
#: remeshing. Measured here: isotropic remeshing runs 20-45k faces x iterations per
#: second on a loaded machine, so 2 M faces x 10 iterations is already minutes, and
#: a tiny target edge (``--resample 0.0001``) would exhaust memory inside pymeshlab.
MAX_RESAMPLE_FACES = 2_000_000


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else f"{text[:40]}... ({len(text)} characters)"


def _check_resample_size(m: Mesh, target: float) -> None:
    """Refuse a target edge whose remeshed mesh would exceed :data:`MAX_RESAMPLE_FACES`.

    An equilateral triangle of edge ``t`` has area ``sqrt(3)/4 t^2``, so the
    output has about ``area / (sqrt(3)/4 t^2)`` faces.
    """
    e1 = m.V[m.F[:, 1]] - m.V[m.F[:, 0]]
    e2 = m.V[m.F[:, 2]] - m.V[m.F[:, 0]]
    area = 0.5 * float(np.linalg.norm(np.cross(e1, e2), axis=1).sum())
    predicted = area / (math.sqrt(3.0) / 4.0 * target * target)
    if predicted > MAX_RESAMPLE_FACES:
        edges, _, _ = topology.edges(m.F)
        mean = float(np.linalg.norm(m.V[edges[:, 0]] - m.V[edges[:, 1]], axis=1).mean())
        smallest = math.sqrt(area / (math.sqrt(3.0) / 4.0 * MAX_RESAMPLE_FACES))
        raise MeshError(
            f"resample: target_edge={target:.4g} would turn {m.name} (area {area:.4g}, mean "
            f"edge {mean:.4g}) into about {predicted:,.0f} faces, more than the "
            f"{MAX_RESAMPLE_FACES:,} allowed; choose a target edge of at least {smallest:.3g} "
            "(or raise igljoin.clean.MAX_RESAMPLE_FACES)"
        )


def resample(
    mesh: Any,
    target_edge: float,
    *,
    keep: Any = None,
    iterations: int = RESAMPLE_ITERATIONS,
) -> tuple[Mesh, ResampleReport]:
    """Remesh a surface to a target edge length, keeping its boundary polylines.

    Long edges (boundary edges included) are first split at their midpoints
    until none is longer than 4/3 of the target
    (``meshing_surface_subdivision_midpoint``), which inserts boundary points
    on the boundary's own straight edges. Then every face that does not touch
    the boundary is remeshed isotropically
    (``meshing_isotropic_explicit_remeshing`` on that selection: the filter
    moves boundary vertices when it may touch them, so faces touching the
    boundary are left out). Finally the output boundary is checked: every
    input boundary vertex is still there at exactly the same position, and
    every output boundary vertex lies on an input boundary edge.

    Parameters
    ----------
    mesh : Mesh or (V, F)
        An edge-manifold surface (run :func:`clean` first otherwise).
    target_edge : float
        Wanted edge length (> 0), e.g. the mean edge of the host seam.
    keep : None, Curve, mapping, int or array_like, optional
        A boundary curve of ``mesh`` (see :class:`igljoin.Curve`) to follow
        into the output: its output vertices are returned in
        :attr:`ResampleReport.kept`. Every boundary is preserved either way.
    iterations : int, optional
        Isotropic remeshing iterations.

    Returns
    -------
    mesh : Mesh
        The resampled mesh (vertex ids change; attributes are dropped).
    report : ResampleReport

    Raises
    ------
    MissingExtraError
        If pymeshlab is not installed.
    MeshError
        If ``target_edge`` is not positive, the mesh is not edge-manifold, or
        the boundary was not preserved.

    Examples
    --------
    >>> import igljoin
    >>> s = igljoin.phantoms.paper_sample(
    ...     "partial_patch", "equal", resolution=0.4, guest_resolution=0.2)
    >>> fine, rep = resample(s.guest, 0.5)
    >>> fine.n_vertices > 10 * s.guest.n_vertices, rep.boundary_deviation < 1e-9
    (True, True)
    """
    m = as_mesh(mesh)
    problem = resample_setting_problem(target_edge, iterations)
    if problem is not None:
        name, value, requirement = problem
        raise MeshError(f"resample: {name}={_short(value)} {requirement}")
    target = float(target_edge)
    info = diagnose(m)
    if info["problems"]["non_manifold_edges"] or info["problems"]["degenerate_faces"]:
        raise MeshError(
            f"resample: {m.name} has non-manifold edges or degenerate faces; repair it with "
            "igljoin.clean.clean first (or cleanup = true in the case spec)"
        )
    _check_resample_size(m, target)
    ml = _pymeshlab("igljoin.clean.resample (remeshing)")
    before = _edge_stats(m.V, m.F)
    loops_in = boundary_loops(m.F)
    edges, _, _ = topology.edges(m.F)
    longest = float(np.linalg.norm(m.V[edges[:, 0]] - m.V[edges[:, 1]], axis=1).max())
    split = 4.0 / 3.0 * target
    subdivisions = 0
    if longest > split:
        subdivisions = int(math.ceil(math.log2(longest / split)))
    ms = _meshset(ml, m.V, m.F, np.arange(m.n_vertices))
    if subdivisions:
        ms.meshing_surface_subdivision_midpoint(
            iterations=subdivisions, threshold=ml.PureValue(split)
        )
    V, F, source = _arrays(ms)
    on_border = np.zeros(len(V), dtype=bool)
    for lp in boundary_loops(F):
        on_border[lp] = True
    inner = ~on_border[F].any(axis=1)
    if inner.any():
        ms = _select_faces(ml, V, F, source, inner)
        ms.meshing_isotropic_explicit_remeshing(
            iterations=int(iterations),
            targetlen=ml.PureValue(target),
            selectedonly=True,
            adaptive=False,
        )
        V, F, _ = _arrays(ms)
    used = np.zeros(len(V), dtype=bool)
    used[F.reshape(-1)] = True
    if not used.all():
        remap = np.cumsum(used) - 1
        V, F = V[used], remap[F]
    loops_out = boundary_loops(F)
    deviation = 0.0
    if loops_in:
        border_out = np.unique(np.concatenate(loops_out)) if loops_out else np.zeros(0, int)
        present = {V[v].tobytes() for v in border_out}
        lost = [v for lp in loops_in for v in lp if m.V[v].tobytes() not in present]
        A, B = _boundary_segments(m.V, loops_in)
        deviation = float(_segment_distance(V[border_out], A, B).max()) if border_out.size else 0.0
        # 1e-9 of the target edge: inserted boundary points are edge midpoints,
        # off their edge by floating-point rounding only
        if lost or len(loops_out) != len(loops_in) or deviation > 1e-9 * target:
            raise MeshError(
                f"resample: remeshing {m.name} changed its boundary ({len(lost)} boundary "
                f"vertices moved, {len(loops_in)} loops before and {len(loops_out)} after, "
                f"largest deviation {deviation:.3g}); the output was discarded"
            )
    out = Mesh(V, F, name=m.name)
    kept = kept_closed = kept_loop = None
    if keep is not None:
        kept, kept_closed, kept_loop = _kept_curve(m, keep, V, loops_out)
    report = ResampleReport(
        target_edge=target,
        subdivisions=subdivisions,
        before=before,
        after=_edge_stats(V, F),
        boundary_deviation=deviation,
        kept=kept,
        kept_closed=kept_closed,
        kept_loop=kept_loop,
    )
    return out, report
