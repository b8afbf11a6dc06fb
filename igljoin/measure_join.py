"""A solved join measured: its :class:`~igljoin.result.JoinResult`, seam by seam and overall.

Per seam: the gap to the host curve, the crease at band scale (of the
result and of the inputs, :mod:`igljoin.crease`), the one-ring crease, the
crease the smooth join removed, the host's own dihedral angles and, with a
``join_angle``, how far the result leaves the host from it. Overall: the
same over all seams, area ratio, strain and displacement maps, folds, then
the weld and its self-intersections (:func:`igljoin.measure.weld_metrics`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from . import crease, metrics
from .bandfit import BandFit, band_fit
from .correspond import Correspondence
from .crease import CreaseMeasure
from .frames import face_normals_areas
from .host_values import HostValues
from .join_terms import JoinTerms, join_angles
from .measure import combined_gap
from .mesh import Mesh
from .options import JoinOptions
from .result import JoinedSeam, JoinResult
from .seam_geometry import SeamGeometry

__all__ = ["join_result"]


def _dihedral_summary(angles: np.ndarray) -> dict:
    return {**metrics.summary(angles), "rings": metrics.HOST_DIHEDRAL_RINGS}


def _rest_fit(rest_fits: dict, corr: Correspondence, at_host, closed, band) -> BandFit:
    """The rest guest's band fit along its seam, made once per set-up (kept in ``rest_fits``)."""
    key = (at_host.tobytes(), bool(closed), float(band))
    if key not in rest_fits:
        rest_fits[key] = band_fit(corr.V, corr.F, at_host, closed, band, compiled=True)
    return rest_fits[key]


def _seam_creases(
    seam: SeamGeometry,
    rest: np.ndarray,
    band: float,
    host_fit: BandFit,
    rest_fit: BandFit,
    host_inward: np.ndarray,
) -> tuple[CreaseMeasure, CreaseMeasure, np.ndarray]:
    """The band crease of the result and of the inputs, and the one-ring crease, of one seam."""
    measured = crease.seam_crease(seam, band, rest, host_fit, rest_fit)
    inputs = crease.input_crease(seam.with_guest(rest), band, host_fit, rest_fit)
    return measured, inputs, metrics.crease_angles(seam, host_inward)


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
    rest_fits: dict,
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
    rest_fits : dict
        The rest guest's band fits along its seams, kept between solves of
        one set-up; filled here.

    Returns
    -------
    JoinResult
    """
    c, X, bc = corr, run.X, targets
    measured_host = host_values.measured  # same vertex ids as the host
    ratio = metrics.area_ratio(c.V, X, c.F)
    strain = metrics.edge_strain(c.V, X, E)
    vertex_strain = metrics.vertex_strain(E, strain, len(X))
    displacement = metrics.nonrigid_displacement(c.V, X)
    on_seam = np.zeros(len(X), dtype=bool)
    on_seam[c.seam] = True
    guest = Mesh(
        X,
        c.F,
        vertex_attributes={
            "displacement": displacement,
            "strain": vertex_strain,
            "seam": on_seam,
        },
        face_attributes={"area_ratio": ratio},
        name="deformed guest",
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
        # the rest guest is fixed too (until the next set-up): its fit along the
        # seam serves both band measures, on every solve
        measured, inputs, onering = _seam_creases(
            geometry,
            c.V,
            band,
            host_values.band_fit(hc, band),
            _rest_fit(rest_fits, c, at_host, hc.closed, band),
            host_values.inward(hc),
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
        gap = metrics.seam_gap(X[part.seam], measured_host.V[hc.indices], hc.closed)
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
                "input_crease_deg": crease.report([inputs]),
                "join_angle_deg": angle,
                "join_angle_error_deg": (
                    crease.report([off_angle_all[-1]]) if off_angle_all else None
                ),
                "crease_removed_deg": metrics.summary(removed[i] if removed else np.zeros(0)),
                "host_dihedral_deg": _dihedral_summary(host_values.dihedral(hc.indices)),
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
    total_ratio = float(face_normals_areas(X, c.F)[1].sum() / face_normals_areas(c.V, c.F)[1].sum())
    m = {
        "seam_gap": combined_gap(gaps, [len(sm.seam) for sm in seams]),
        "crease_deg": crease.report(measured_all),
        "crease_onering_deg": metrics.summary(np.concatenate(onering_all)),
        "input_crease_deg": crease.report(inputs_all),
        "join_angle_error_deg": crease.report(off_angle_all) if off_angle_all else None,
        "host_dihedral_deg": _dihedral_summary(host_values.dihedral(host_curve)),
        "area_ratio": {**metrics.summary(ratio), "total": total_ratio},
        "area_change": metrics.summary(np.abs(ratio - 1.0)),
        "strain": metrics.summary(strain),
        "vertex_strain": metrics.summary(vertex_strain),
        "displacement_nonrigid": metrics.summary(displacement),
        "folded_pairs": len(metrics.folded_pairs(c.V, X, c.F)),
        "crease_removed_deg": metrics.summary(np.concatenate(removed) if removed else np.zeros(0)),
        "seams": per_seam,
    }
    result = JoinResult(
        host=host,
        guest=guest,
        rest_guest=Mesh(c.V, c.F, name="rest guest"),
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
