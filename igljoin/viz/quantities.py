"""Per-vertex and per-face fields shown on the deformed guest (NumPy/SciPy only).

Each field is taken from the result when it carries it (``vertex_strain``,
``displacement``... or a numeric per-vertex attribute of ``result.guest``)
and computed here otherwise, so the inspection works with any
:class:`~igljoin.JoinResult`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..frames import seam_frames
from ..metrics import edge_strain, nonrigid_displacement, vertex_strain
from ..terms import LocalState, unique_edges

__all__ = [
    "cross_seam_directions",
    "seam_curves",
    "guest_fields",
    "vertex_edge_strain",
    "vertex_energy",
]

#: Result attributes a per-vertex field may be published under (first present wins).
_RESULT_FIELDS = {
    "edge strain": ("vertex_strain", "strain_per_vertex", "strain"),
    "displacement": ("vertex_displacement", "displacement_per_vertex", "displacement"),
    "energy": ("vertex_energy", "energy_per_vertex"),
}


def vertex_edge_strain(V0: np.ndarray, V1: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Mean relative length change ``(ℓ′ − ℓ)/ℓ`` (n,) of the edges at each vertex.

    ``V0``, ``V1`` (n, 3) are the rest and deformed positions, ``F`` (m, 3)
    the faces; > 0 stretched, < 0 shrunk.
    """
    E = unique_edges(F)
    return np.nan_to_num(vertex_strain(E, edge_strain(V0, V1, E), len(V0)))


def vertex_energy(solver: Any, X: np.ndarray) -> np.ndarray | None:
    """The solver's energy at ``X`` split over the vertices, shape (n,), or ``None``.

    Each row ``r`` of each term contributes ``w_r ‖(K X)_r − target_r‖²``,
    shared equally by the vertices that row involves; the fields sum to the
    total energy.

    Parameters
    ----------
    solver : JoinSolver or None
        Its ``terms`` must be those that produced ``X``.
    X : ndarray, shape (n, 3)
        Deformed guest positions.

    Returns
    -------
    ndarray, shape (n,) or None
        ``None`` without a solver (a bare result carries no terms).
    """
    terms = getattr(solver, "terms", None)
    if not terms or X.shape[0] != terms[0].K.shape[1]:
        return None
    state = LocalState(np.asarray(X, dtype=np.float64))
    out = np.zeros(X.shape[0])
    for term in terms:  # a handful of terms, each vectorised
        r = term.applied(state) - term.target(state)
        e = term.weights * np.einsum("ij,ij->i", r, r)
        A = (abs(term.K) > 0).astype(np.float64).tocsr()
        per_row = np.asarray(A.sum(axis=1)).reshape(-1)
        out += A.T @ (e / np.maximum(per_row, 1.0))
    return out


def _from_result(result: Any, names: tuple[str, ...], n: int) -> np.ndarray | None:
    for name in names:
        value = getattr(result, name, None)
        if value is None:
            value = result.guest.vertex_attributes.get(name)
        if value is None:
            continue
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            continue
        if arr.ndim == 2 and arr.shape == (n, 3):
            arr = np.linalg.norm(arr, axis=1)
        if arr.shape == (n,):
            return arr
    return None


def guest_fields(result: Any, solver: Any = None) -> dict[str, np.ndarray]:
    """Per-vertex fields of the deformed guest, by display name.

    Parameters
    ----------
    result : JoinResult
    solver : JoinSolver, optional
        Adds ``"energy"`` (see :func:`vertex_energy`).

    Returns
    -------
    dict of str to ndarray, shape (n,)
        ``"edge strain"`` and ``"displacement"`` always; ``"energy"`` when
        available; and every other numeric per-vertex attribute of
        ``result.guest`` as ``"attribute <name>"``.
    """
    V0, V1, F = result.rest_guest.V, result.guest.V, result.guest.F
    n = len(V1)
    fields = {
        "edge strain": _from_result(result, _RESULT_FIELDS["edge strain"], n),
        "displacement": _from_result(result, _RESULT_FIELDS["displacement"], n),
        "energy": _from_result(result, _RESULT_FIELDS["energy"], n),
    }
    if fields["edge strain"] is None:
        fields["edge strain"] = vertex_edge_strain(V0, V1, F)
    if fields["displacement"] is None:
        fields["displacement"] = nonrigid_displacement(V0, V1)
    if fields["energy"] is None:
        fields["energy"] = vertex_energy(solver, V1)
    used = {name for names in _RESULT_FIELDS.values() for name in names}
    for key, value in result.guest.vertex_attributes.items():
        arr = np.asarray(value)
        if key not in used and arr.shape == (n,) and np.issubdtype(arr.dtype, np.number):
            fields[f"attribute {key}"] = arr.astype(np.float64)
    return {k: v for k, v in fields.items() if v is not None}


def cross_seam_directions(result: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Host and guest cross-seam tangents at the host curve vertices.

    Returns
    -------
    points : ndarray, shape (k, 3)
        Host curve vertices.
    normal : ndarray, shape (k, 3)
        Unit host surface normal there (its sign follows the host's faces).
    host : ndarray, shape (k, 3)
        Unit direction in which the host surface, continued smoothly, leaves
        the seam (minus the host's inward direction, paper §4.4).
    guest : ndarray, shape (k, 3)
        Unit direction in which the deformed guest leaves the seam. For a
        smooth join the two coincide; the angle between them is the crease.
    """
    host = result.host
    parts = []
    for curve, at_host, closed in seam_curves(result):
        P = host.V[curve]
        h = seam_frames(host.V, host.F, curve, closed)
        g = seam_frames(result.guest.V, result.guest.F, at_host, closed, curve_points=P)
        parts.append((P, h.normal, -h.inward, g.inward))
    return tuple(np.concatenate(column) for column in zip(*parts))


def seam_curves(result: Any) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """Per seam of ``result``: host curve, guest vertex on each host curve vertex, closed."""
    seams = getattr(result, "seams", None)
    if seams:
        return [(sm.host_curve, sm.seam[sm.host_hit], sm.closed) for sm in seams]
    return [(result.host_curve, result.guest_at_host, result.closed)]
