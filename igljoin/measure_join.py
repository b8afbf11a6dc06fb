"""A solved join measured: its :class:`~igljoin.result.JoinResult`, seam by seam and overall.

Per seam: the gap to the host curve, the crease at band scale (of the
result and of the inputs, :mod:`igljoin.crease`), the one-ring crease, the
crease the smooth join removed, the host's own dihedral angles and, with a
``join_angle``, how far the result leaves the host from it. Overall: the
same over all seams, area ratio, strain and displacement maps, folds, then
the weld and its self-intersections (:func:`igljoin.measure.weld_metrics`).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from . import crease, metrics
from .bandfit import BandFit, band_fit
from .correspond import Correspondence, RigidReference, rigid_reference
from .crease import CreaseMeasure
from .frames import CurveFaces, face_areas, face_normals_areas
from .host_values import HostValues
from .join_terms import JoinTerms, join_angles
from .measure import combined_gap
from .mesh import Mesh
from .options import JoinOptions
from .result import JoinedSeam, JoinResult
from .seam_geometry import SeamGeometry

__all__ = ["join_result", "RestMeasures"]


def _dihedral_summary(angles: np.ndarray) -> dict:
    return {**metrics.summary(angles), "rings": metrics.HOST_DIHEDRAL_RINGS}


def _fixed_reports_of(
    inputs: list[CreaseMeasure],
    removed: Callable[[], np.ndarray],
    dihedral: Callable[[], np.ndarray],
) -> dict:
    """The reports of a join that no solve changes, for one seam or all.

    Parameters
    ----------
    inputs : list of CreaseMeasure
        The inputs' band crease, one per seam.
    removed : callable
        Makes the crease the smooth-join terms remove (degrees), shape (r,).
    dihedral : callable
        Makes the host's dihedral angles near the curves (degrees), shape (d,).
        Both are called only here, when the reports are first made.

    Returns
    -------
    dict
        ``input_crease_deg``, ``crease_removed_deg``, ``host_dihedral_deg``.
    """
    return {
        "input_crease_deg": crease.report(inputs),
        "crease_removed_deg": metrics.summary(removed()),
        "host_dihedral_deg": _dihedral_summary(dihedral()),
    }


def _removed(removed: list[np.ndarray], seam: int | None) -> np.ndarray:
    """The crease the terms remove (degrees) along seam ``seam``, or all seams' (``None``)."""
    if not removed:
        return np.zeros(0)
    return np.concatenate(removed) if seam is None else removed[seam]


def _deformed_guest(X: np.ndarray, faces: np.ndarray, vertex: dict, face: dict) -> Mesh:
    """The deformed guest as a :class:`Mesh` named "deformed guest".

    Of the join's own arrays, unchecked (a copy of ``X``, a view of the kept
    read-only ``faces``, the attributes as made); positions that are not all
    finite (a solve gone wrong) go through the checks, which refuse them.
    """
    if not np.isfinite(X).all():
        return Mesh(X, faces, vertex, face, name="deformed guest")
    V = np.array(X, dtype=np.float64, order="C")
    return Mesh._of_own_arrays(V, faces.view(), vertex, face, name="deformed guest")


class RestMeasures:
    """The rest guest's side of a join's measures, made on first use and kept by a solver.

    The rest guest is fixed until the next set-up, so its band fits along the
    seams, the input crease, its face areas and edge lengths, its adjacent
    face pairs, its faces along each seam (with their weights' rows and the
    curve's tangents), its edges' incidence, its centred positions and its
    read-only arrays are the same on every solve; a re-solve measures only
    what its new positions change.

    Parameters
    ----------
    corr : Correspondence
        Of all seams (the refined rest guest).
    E : ndarray of int64, shape (e, 2)
        Its unique edges.
    """

    def __init__(self, corr: Correspondence, E: np.ndarray):
        self.corr, self.E = corr, E
        self.made: dict[tuple, Any] = {}

    def _kept(self, key: tuple, make: Callable[[], Any]) -> Any:
        if key not in self.made:
            self.made[key] = make()
        return self.made[key]

    def fit(self, curve: np.ndarray, closed: bool, band: float, *, keep: bool = True) -> BandFit:
        """The rest guest's band fit along ``curve``, shape (k,) (serves both band measures).

        The smooth-join terms take theirs, along the whole seam, from here
        too (``keep=False``): where every seam vertex lies on a host curve
        vertex the two are one fit, the one kept; where host points were
        inserted into the seam the whole seam's fit is made for the term and
        not kept (the measures read the host curve's only; on the
        1M-vertex tube it is 0.32 GB).
        """
        c = self.corr
        key = ("fit", np.asarray(curve).tobytes(), bool(closed), float(band))
        if not keep and key not in self.made:
            return band_fit(c.V, c.F, curve, closed, band)
        return self._kept(key, lambda: band_fit(c.V, c.F, curve, closed, band))

    def input_crease(
        self, seam: SeamGeometry, band: float, host_fit: BandFit, rest_fit: BandFit
    ) -> CreaseMeasure:
        """:func:`igljoin.crease.input_crease` of ``seam`` with the rest guest."""
        key = ("input", seam.guest_at_host.tobytes(), seam.host_curve.tobytes(), float(band))
        return self._kept(
            key,
            lambda: crease.input_crease(seam.with_guest(self.corr.V), band, host_fit, rest_fit),
        )

    def reports(self, key: tuple, make: Callable[[], dict]) -> dict:
        """Reports of what a solve does not change (the inputs' crease, the host's angles, the
        crease the terms remove), made once per ``key``; a copy of each, so a result's
        metrics are its own.

        Parameters
        ----------
        key : tuple
            Names the reports within the set-up (e.g. the seam's number).
        make : callable
            Returns a dict of flat dicts (name to summary).

        Returns
        -------
        dict
        """
        return {name: dict(value) for name, value in self._kept(key, make).items()}

    def guest_curve_faces(self, seam: SeamGeometry) -> CurveFaces:
        """:func:`igljoin.metrics.guest_curve_faces` of ``seam`` (its guest's faces there)."""
        # the host is rigid through a solver's life, so its curve's points and tangents (which
        # the kept faces hold) are fixed by the curve's indices
        key = ("curve faces", seam.guest_at_host.tobytes(), seam.host_curve.tobytes(), seam.closed)
        return self._kept(key, lambda: metrics.guest_curve_faces(seam))

    @property
    def areas(self) -> np.ndarray:
        """Face areas, shape (m,)."""
        return self._kept(("areas",), lambda: face_areas(self.corr.V, self.corr.F))

    @property
    def coordinate_major(self) -> tuple[np.ndarray, np.ndarray]:
        """The faces (m, 3) and the edges ``E`` (e, 2), each the transpose of a C-ordered copy."""
        return self._kept(
            ("coordinate major",),
            lambda: tuple(np.ascontiguousarray(A.T).T for A in (self.corr.F, self.E)),
        )

    @property
    def incidence(self) -> metrics.VertexIncidence:
        """The edges' ends, each vertex's edge count (:func:`igljoin.metrics.vertex_incidence`)."""
        n = len(self.corr.V)
        return self._kept(("incidence",), lambda: metrics.vertex_incidence(self.E, n))

    @property
    def rigid(self) -> RigidReference:
        """The rest side of the rigid fit of the non-rigid displacement
        (:func:`igljoin.correspond.rigid_reference`)."""
        return self._kept(("rigid",), lambda: rigid_reference(self.corr.V))

    def rest_guest(self) -> Mesh:
        """The rest guest as a :class:`Mesh` named "rest guest", made of read-only views.

        Its arrays are views of read-only copies kept here, so every result
        has a mesh of its own at no copy; nobody can write to them.
        """
        V, F = self._kept(("rest guest",), self._rest_arrays)
        return Mesh._of_own_arrays(V.view(), F.view(), name="rest guest")

    @property
    def faces(self) -> np.ndarray:
        """The faces as a :class:`Mesh` holds them (int64, C-ordered, read-only), shape (m, 3)."""
        return self._kept(("rest guest",), self._rest_arrays)[1]

    def _rest_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        V = np.array(self.corr.V, dtype=np.float64, order="C")
        F = np.array(self.corr.F, dtype=np.int64, order="C")
        V.flags.writeable = F.flags.writeable = False
        return V, F

    @property
    def edge_lengths(self) -> np.ndarray:
        """Lengths of the edges ``E``, shape (e,)."""
        return self._kept(("lengths",), lambda: metrics.edge_lengths(self.corr.V, self.E))

    @property
    def folds(self) -> metrics.FoldReference:
        """Adjacent face pairs and their rest cosines (:func:`igljoin.metrics.fold_reference`)."""
        return self._kept(("folds",), lambda: metrics.fold_reference(self.corr.V, self.corr.F))


def join_result(
    run: Any,
    targets: np.ndarray,
    *,
    options: JoinOptions,
    host: Mesh,
    host_offsets: np.ndarray,
    host_values: HostValues,
    pairs: list,
    parts: list[Correspondence],
    corr: Correspondence,
    E: np.ndarray,
    bands: list[float],
    built: JoinTerms,
    rest: RestMeasures,
) -> JoinResult:
    """The result of a solve, with its measurements and its weld.

    Parameters
    ----------
    run : IterationResult
        The solve (:meth:`igljoin.solve.LocalGlobalSolver.run`): positions
        ``X`` of the refined guest, iterations, energies, stop reason.
    targets : ndarray, shape (s, 3)
        The seam targets it was solved for, seam after seam.
    options : JoinOptions
    host : Mesh
        The (combined) host.
    host_offsets : ndarray of int64
        First vertex of each host mesh in ``host``.
    host_values : HostValues
        The host's kept values; ``host_values.measured`` is the host the
        one-ring measures read.
    pairs : list of SeamPair
    parts : list of Correspondence
        Each seam's own correspondence.
    corr : Correspondence
        Of all seams (the refined rest guest).
    E : ndarray of int64, shape (e, 2)
        Unique edges of the refined guest.
    bands : list of float
        Each seam's band width.
    built : JoinTerms
        The terms of the solve (their soft rows, the crease they remove).
    rest : RestMeasures
        The rest guest's measures, kept between solves of one set-up.

    Returns
    -------
    JoinResult
    """
    c, X, bc = corr, run.X, targets
    measured_host = host_values.measured  # same vertex ids as the host
    # the positions, faces and edges coordinate-major, as the face and edge measures read
    # them: their own np.ascontiguousarray(A.T) is then no copy
    Xc = np.ascontiguousarray(X.T).T
    Fc, Ec = rest.coordinate_major
    normals, areas = face_normals_areas(Xc, Fc)
    ratio = metrics.area_ratio(c.V, X, c.F, rest_areas=rest.areas, areas=areas)
    strain = metrics.edge_strain(c.V, Xc, Ec, rest_lengths=rest.edge_lengths)
    vertex_strain = metrics.vertex_strain(E, strain, len(X), incidence=rest.incidence)
    displacement = metrics.nonrigid_displacement(c.V, X, rest=rest.rigid)
    on_seam = np.zeros(len(X), dtype=bool)
    on_seam[c.seam] = True
    guest = _deformed_guest(
        X,
        rest.faces,
        {"displacement": displacement, "strain": vertex_strain, "seam": on_seam},
        {"area_ratio": np.array(ratio)},
    )
    seams, per_seam, gaps = [], [], []
    start = 0
    onering_all, measured_all, inputs_all, off_angle_all = [], [], [], []
    asked = join_angles(options, len(pairs)) if options.smooth_mode == "band" else []
    asked = asked if options.smooth else []
    removed = built.crease_removed
    for i, (p, part, band) in enumerate(zip(pairs, parts, bands)):
        hc = p.host_curve
        s = len(part.seam)
        at_host = part.seam[part.host_hit]
        geometry = SeamGeometry(
            measured_host.V, measured_host.F, hc.indices, X, c.F, at_host, hc.closed
        )
        # the band crease of the result and of the inputs, and the one-ring crease
        host_fit, rest_fit = host_values.band_fit(hc, band), rest.fit(at_host, hc.closed, band)
        measured = crease.seam_crease(geometry, band, c.V, host_fit, rest_fit)
        inputs = rest.input_crease(geometry, band, host_fit, rest_fit)
        fixed = rest.reports(
            ("seam reports", i),
            partial(
                _fixed_reports_of,
                [inputs],
                partial(_removed, removed, i),
                partial(host_values.dihedral, hc.indices),
            ),
        )
        onering = metrics.crease_angles(
            geometry, host_values.inward(hc), guest_faces=rest.guest_curve_faces(geometry)
        )
        measured_all.append(measured)
        inputs_all.append(inputs)
        onering_all.append(onering)
        angle = asked[i] if asked else None
        if any(asked):
            # how far the guest leaves the host from the angle asked for (0 where
            # a seam keeps the smooth join)
            off = np.abs(measured.angles - (angle or 0.0))
            off_angle_all.append(CreaseMeasure(off, band, measured.noise))
        gap = metrics.seam_gap(X[part.seam], host_values.distance(hc))
        gaps.append(gap)
        seams.append(
            JoinedSeam(
                host_index=p.host_index,
                host_curve=hc.indices.copy(),
                seam=part.seam.copy(),
                closed=hc.closed,
                targets=np.array(bc[start : start + s]),
                host_hit=part.host_hit.copy(),
                host_edge=part.host_edge.copy(),
                host_edge_t=part.host_edge_t.copy(),
                inserted=len(part.inserted_t),
                crease=measured.angles,
                pairing=dict(p.pairing),
            )
        )
        per_seam.append(
            {
                "host_index": p.host_index,
                "closed": hc.closed,
                "seam": s,
                "host_curve": len(hc.indices),
                "inserted": len(part.inserted_t),
                "seam_gap": gap,
                "crease_deg": crease.report([measured]),
                "crease_onering_deg": metrics.summary(onering),
                "input_crease_deg": fixed["input_crease_deg"],
                "join_angle_deg": angle,
                "join_angle_error_deg": (
                    crease.report([off_angle_all[-1]]) if off_angle_all else None
                ),
                "crease_removed_deg": fixed["crease_removed_deg"],
                "host_dihedral_deg": fixed["host_dihedral_deg"],
            }
        )
        start += s
    host_curve = np.concatenate([sm.host_curve for sm in seams])
    counts = {
        "points": len(c.V),
        "hard": 3 * len(c.seam),
        "soft": 3 * sum(t.soft_rows for t in built.terms),
        "seam": len(c.seam),
        "inserted": len(c.inserted_t),
        "faces": len(c.F),
        "host_curve": len(host_curve),
        "seams": len(seams),
    }
    total_ratio = float(areas.sum() / rest.areas.sum())
    fixed = rest.reports(
        ("reports",),
        partial(
            _fixed_reports_of,
            inputs_all,
            partial(_removed, removed, None),
            partial(host_values.dihedral, host_curve),
        ),
    )
    if len(per_seam) == 1:
        # one seam: the reports over all seams are its own (the same values in the same
        # order), each a copy of its own
        only = per_seam[0]
        crease_deg, onering_deg, error_deg = (
            None if only[name] is None else dict(only[name])
            for name in ("crease_deg", "crease_onering_deg", "join_angle_error_deg")
        )
    else:
        crease_deg = crease.report(measured_all)
        onering_deg = metrics.summary(np.concatenate(onering_all))
        error_deg = crease.report(off_angle_all) if off_angle_all else None
    m = {
        "seam_gap": combined_gap(gaps, [len(sm.seam) for sm in seams]),
        "crease_deg": crease_deg,
        "crease_onering_deg": onering_deg,
        "input_crease_deg": fixed["input_crease_deg"],
        "join_angle_error_deg": error_deg,
        "host_dihedral_deg": fixed["host_dihedral_deg"],
        "area_ratio": {**metrics.summary(ratio), "total": total_ratio},
        "area_change": metrics.summary(np.abs(ratio - 1.0)),
        "strain": metrics.summary(strain),
        "vertex_strain": metrics.summary(vertex_strain),
        "displacement_nonrigid": metrics.summary(displacement),
        "folded_pairs": len(metrics.folded_pairs(c.V, X, c.F, rest=rest.folds, normals=normals)),
        "crease_removed_deg": fixed["crease_removed_deg"],
        "seams": per_seam,
    }
    result = JoinResult(
        host=host,
        guest=guest,
        rest_guest=rest.rest_guest(),
        seams=seams,
        seam_targets=np.array(bc),
        area_ratio=ratio,
        converged=run.converged,
        iterations=run.iterations,
        energy=list(run.energy),
        counts=counts,
        timings={},
        options=options,
        correspondence=c,
        crease=np.concatenate([sm.crease for sm in seams]),
        metrics=m,
        stop_reason=run.reason,
        host_offsets=host_offsets.copy(),
    )
    # weld (kept in the result) and count self-intersections near the seam
    result.metrics.update(result.measure_weld())
    return result
