"""Quality warnings: what in a finished join a user must look at before trusting it.

:func:`assess` reads a :class:`~igljoin.result.JoinResult` (its metrics,
convergence and input curves) and returns one :class:`QualityWarning` per
problem found, each with the measured value, the threshold it crossed and
what to do about it. A clean join has none. ``docs/warnings.md`` lists every
code with its threshold.

The thresholds are module constants, so a pipeline can read (or, at its own
risk, change) them; each is chosen so that the paper's six samples
(:func:`igljoin.phantoms.paper_samples`) join without a warning while the
failures seen on real cuts are flagged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .polyline import segment_lengths

__all__ = [
    "AREA_RATIO_FACE_LIMIT",
    "AREA_RATIO_TOTAL_LIMIT",
    "CODES",
    "CREASE_MAX_DEG",
    "HOST_CREASE_DEG",
    "SEAM_SLIVER_FRACTION",
    "SEAM_UNEVEN_RATIO",
    "QualityWarning",
    "assess",
    "curve_warnings",
]

#: Largest seam crease (degrees) taken as a smooth join, read as
#: ``metrics["crease_deg"]["beyond_noise_max"]``: the largest crease less twice
#: its standard error, so that the band fits' own noise on a real scan (2–12°
#: on the pymeshlab samples) does not raise it. 10° is a kink a rendering shows
#: plainly, and an order of magnitude above what the smooth join leaves on the
#: paper's samples (at most 1.6°). Where the inputs already met at that crease
#: the warning is ``host_creased`` instead.
CREASE_MAX_DEG = 10.0

#: Crease (degrees, ``metrics["input_crease_deg"]["beyond_noise_max"]``) the
#: inputs must meet at for a crease of the result to count as theirs
#: (``host_creased``: a feature along the seam that the join kept) rather than
#: the join's (``crease``). The same 10° as :data:`CREASE_MAX_DEG`. A crease the
#: inputs meet at and the join removed (a guest that arrives at an angle, as in
#: the paper's samples) raises nothing: ``input_crease_deg`` reports it.
HOST_CREASE_DEG = 10.0

#: Largest factor by which one guest face may grow or shrink (area ratio
#: above this or below its inverse). A face at 4x or 1/4 of its area has
#: stretched its edges by about 2x, far past what soft tissue takes; the
#: paper's samples stay within 0.40 to 2.01.
AREA_RATIO_FACE_LIMIT = 4.0

#: Largest factor by which the guest's total area may change. Doubling or
#: halving the whole guest means the curves do not match in length or the
#: wrong curves were joined; the paper's samples stay within 0.92 to 1.55
#: (their "shorter" and "longer" guests are made to need stretching).
AREA_RATIO_TOTAL_LIMIT = 2.0

#: A seam or host curve segment shorter than this fraction of the curve's
#: median segment is a sliver (what clipping a mesh by a plane leaves where
#: the plane passes near a vertex). Tangents, normals and the crease measured
#: at such a segment follow its rounding rather than the surface.
SEAM_SLIVER_FRACTION = 0.1

#: Longest over median segment of a seam or host curve above which the curve
#: is very uneven: the join then holds the guest at far fewer points along
#: part of the seam than along the rest, and the correspondence spreads one
#: host segment over many guest vertices there.
SEAM_UNEVEN_RATIO = 5.0

#: Every warning code, in the order :func:`assess` reports them.
CODES = (
    "not_converged",
    "crease",
    "host_creased",
    "folds",
    "weld_failed",
    "self_intersections",
    "area_change",
    "seam_slivers",
    "seam_uneven",
)


@dataclass(frozen=True)
class QualityWarning:
    """One problem found in a join.

    Attributes
    ----------
    code : str
        Short name, one of :data:`CODES` (stable: scripts may test it).
    message : str
        What is wrong, with the figures, and what the user can do.
    value : float or None
        The measured value that crossed the threshold (None if there is no
        single figure, e.g. a weld that failed).
    threshold : float or None
        The threshold it crossed (None where there is none).
    """

    code: str
    message: str
    value: float | None = None
    threshold: float | None = None

    def to_json(self) -> dict:
        """``{"code", "message", "value", "threshold"}`` as plain JSON (NaN becomes None)."""
        return {
            "code": self.code,
            "message": self.message,
            "value": _plain(self.value),
            "threshold": _plain(self.threshold),
        }


def _plain(x: Any) -> float | int | None:
    if x is None:
        return None
    if isinstance(x, (int, np.integer)) and not isinstance(x, bool):
        return int(x)
    x = float(x)
    return x if np.isfinite(x) else None


def _number(d: Any, *keys: str) -> float | None:
    """``d[k0][k1]...`` as a finite float, or None if missing or not a finite number."""
    for k in keys:
        if not isinstance(d, dict):
            return None
        d = d.get(k)
    if isinstance(d, bool) or not isinstance(d, (int, float, np.integer, np.floating)):
        return None
    return float(d) if np.isfinite(d) else None


def _curves(result: Any) -> list[tuple[str, np.ndarray]]:
    """(name, segment lengths) of each input curve: the host curves and the guest seams.

    Guest seams are taken over the guest's own vertices only (the vertices
    inserted where host points fall are left out: they are the join's, not
    the input's).
    """
    corr = result.correspondence
    n_original = len(result.rest_guest.V) - len(corr.inserted_t)
    several = len(result.seams) > 1
    out = []
    for i, sm in enumerate(result.seams):
        tag = f" {i}" if several else ""
        out.append((f"host curve{tag}", segment_lengths(result.host.V[sm.host_curve], sm.closed)))
        own = sm.seam[sm.seam < n_original]
        if len(own) >= 2:
            out.append((f"guest seam{tag}", segment_lengths(result.rest_guest.V[own], sm.closed)))
    return out


def curve_warnings(curves) -> list[QualityWarning]:
    """``seam_slivers`` and ``seam_uneven`` warnings of some curves (at most one of each).

    Parameters
    ----------
    curves : iterable of (str, ndarray of shape (k,))
        Each curve's name (used in the message, e.g. ``"host curve"``) and
        its segment lengths (:func:`segment_lengths`). Curves of fewer than
        three segments are skipped.

    Returns
    -------
    list of QualityWarning
        The worst sliver over all curves, then the worst uneven curve.

    Examples
    --------
    >>> import numpy as np
    >>> [w.code for w in curve_warnings([("host curve", np.array([1.0, 1, 1, 0.01]))])]
    ['seam_slivers']
    """
    worst_sliver, worst_uneven = None, None
    for name, lengths in curves:
        lengths = np.asarray(lengths, dtype=np.float64)
        lengths = lengths[np.isfinite(lengths)]
        if len(lengths) < 3:
            continue
        median = float(np.median(lengths))
        if median <= 0:
            continue
        short, long = float(lengths.min()) / median, float(lengths.max()) / median
        n_short = int((lengths < SEAM_SLIVER_FRACTION * median).sum())
        if short < SEAM_SLIVER_FRACTION and (worst_sliver is None or short < worst_sliver[0]):
            worst_sliver = (short, name, n_short, len(lengths))
        if long > SEAM_UNEVEN_RATIO and (worst_uneven is None or long > worst_uneven[0]):
            worst_uneven = (long, name, float(lengths.max() / lengths.min()))
    out = []
    if worst_sliver is not None:
        short, name, n_short, n = worst_sliver
        out.append(
            QualityWarning(
                "seam_slivers",
                f"the {name} has {n_short} of its {n} segments shorter than "
                f"{SEAM_SLIVER_FRACTION:g} of its median segment (the shortest {short:.2g} of it), "
                "as a plane clip leaves them; directions measured there follow rounding, not the "
                "surface: remesh the seam band evenly before joining (igljoin.clean.resample, or "
                "resample = true in join.toml) or collapse the short edges",
                short,
                SEAM_SLIVER_FRACTION,
            )
        )
    if worst_uneven is not None:
        long, name, spread = worst_uneven
        out.append(
            QualityWarning(
                "seam_uneven",
                f"the {name} is very uneven: its longest segment is {long:.3g} times its median "
                f"one (longest over shortest {spread:.3g}), above {SEAM_UNEVEN_RATIO:g}; the join "
                "holds the guest at few points there: resample the curve evenly before joining "
                "(igljoin.clean.resample, or resample = true in join.toml)",
                long,
                SEAM_UNEVEN_RATIO,
            )
        )
    return out


def _area_warning(m: dict) -> QualityWarning | None:
    lo, hi = _number(m, "area_ratio", "min"), _number(m, "area_ratio", "max")
    total = _number(m, "area_ratio", "total")
    face, whole = AREA_RATIO_FACE_LIMIT, AREA_RATIO_TOTAL_LIMIT
    # (how far past its limit, as a factor >= 1; what; value; the limit it crossed)
    found = []
    if lo is not None and (lo <= 0 or 1.0 / lo > face):
        excess = np.inf if lo <= 0 else 1.0 / lo / face
        found.append((excess, f"a guest face shrank to {lo:.3g} of its area", lo, 1 / face))
    if hi is not None and hi > face:
        found.append((hi / face, f"a guest face grew to {hi:.3g} times its area", hi, face))
    if total is not None and total > 0 and max(total, 1 / total) > whole:
        found.append(
            (
                max(total, 1 / total) / whole,
                f"the guest's total area changed by a factor {total:.3g}",
                total,
                whole if total > 1 else 1 / whole,
            )
        )
    if not found:
        return None
    _, what, value, threshold = max(found, key=lambda f: f[0])
    shown = " to ".join("n/a" if x is None else f"{x:.3g}" for x in (lo, hi))
    return QualityWarning(
        "area_change",
        f"{what} (face area ratios {shown}; the limits are {1 / face:g} to {face:g} per face and "
        f"{1 / whole:g} to {whole:g} for the whole guest): the guest had to squeeze or stretch "
        "grossly; check that the two curves match in length and units and that the right "
        "curves are selected, or give the guest a different size or shape",
        value,
        threshold,
    )


def _beyond_noise(m: dict, key: str) -> float | None:
    """The largest crease of ``m[key]`` the band fits tell from their noise (or its max)."""
    value = _number(m, key, "beyond_noise_max")
    return _number(m, key, "max") if value is None else value


def _where(si: dict) -> str:
    """Where self-intersections are: the pairs per seam and the centre of each seam's."""
    per_seam, centres = si.get("per_seam"), si.get("centres")
    if not isinstance(per_seam, list) or not isinstance(centres, list):
        return ""
    parts = []
    for i, (count, centre) in enumerate(zip(per_seam, centres)):
        if count and isinstance(centre, list) and len(centre) == 3:
            at = "(" + ", ".join(f"{c:.3g}" for c in centre) + ")"
            parts.append((f"seam {i}: {count} " if len(per_seam) > 1 else "") + f"around {at}")
    return (", " + "; ".join(parts)) if parts else ""


def _join_angle_warning(m: dict) -> list[QualityWarning]:
    """``crease`` for a join at a given angle: the guest leaves the host at another one."""
    off = _beyond_noise(m, "join_angle_error_deg")
    if off is None or off <= CREASE_MAX_DEG:
        return []
    peak = _number(m, "join_angle_error_deg", "max")
    return [
        QualityWarning(
            "crease",
            f"the guest leaves the host up to {peak if peak is not None else off:.1f}° away "
            f"from the join angle asked for (beyond {CREASE_MAX_DEG:g}° even less twice the "
            "fits' noise): check that the curves correspond, and raise smooth_weight or "
            "give the guest a rest shape nearer that angle",
            off,
            CREASE_MAX_DEG,
        )
    ]


def _crease_warnings(m: dict, band_join: bool) -> list[QualityWarning]:
    """``crease`` or ``host_creased``: a crease in the result, made by the join or kept.

    ``band_join``: the band smooth join ran with its default targets, which keep
    a crease of the inputs that is not coherent along the seam; only then can a
    crease of the result be the inputs' own (``host_creased``).
    """
    crease = _beyond_noise(m, "crease_deg")
    if crease is None or crease <= CREASE_MAX_DEG:
        return []
    peak, mean = _number(m, "crease_deg", "max"), _number(m, "crease_deg", "mean")
    noise = _number(m, "crease_deg", "noise")
    seen = (
        f"up to {peak if peak is not None else crease:.1f}° (mean "
        f"{mean if mean is not None else float('nan'):.1f}°"
        + (f", fits' noise {noise:.1f}°" if noise is not None else "")
        + ")"
    )
    inputs = _beyond_noise(m, "input_crease_deg")
    if band_join and inputs is not None and inputs > HOST_CREASE_DEG:
        return [
            QualityWarning(
                "host_creased",
                f"the guest meets the host at a crease of {seen} that the inputs already "
                f"meet at (up to {_number(m, 'input_crease_deg', 'max') or inputs:.1f}° before "
                "the join): a feature of the host or the guest along the seam, which the smooth "
                "join keeps because it is not coherent along the seam; if it should go, give "
                "join_angle = 0, or a finer guest and host near the seam",
                crease,
                HOST_CREASE_DEG,
            )
        ]
    return [
        QualityWarning(
            "crease",
            f"the guest meets the host at a crease of {seen}, beyond {CREASE_MAX_DEG:g}° even "
            "less twice the fits' noise: the join is not smooth there; check that the curves "
            "correspond (start, direction), keep smooth = true and raise smooth_weight",
            crease,
            CREASE_MAX_DEG,
        )
    ]


def assess(result: Any) -> tuple[QualityWarning, ...]:
    """The quality warnings of a join (empty for a clean one).

    Parameters
    ----------
    result : JoinResult
        Reads ``metrics``, ``converged``, ``stop_reason``, ``iterations``,
        ``options``, ``seams``, ``host``, ``rest_guest`` and
        ``correspondence``; a metric that is missing raises no warning.

    Returns
    -------
    tuple of QualityWarning
        In the order of :data:`CODES`.

    Examples
    --------
    Without the smooth-join term the end-to-end sample meets its host at a
    kink:

    >>> import igljoin
    >>> s = igljoin.phantoms.paper_sample("end_to_end", "equal", resolution=0.5)
    >>> res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, smooth=False)
    >>> [w.code for w in assess(res) if w.code == "crease"]
    ['crease']
    >>> res.warnings == assess(res)  # the result keeps its own
    True
    """
    m = result.metrics or {}
    out: list[QualityWarning] = []
    if not result.converged:
        limit = getattr(result.options, "max_iterations", None)
        why = {
            "max_iterations": f"it used all {limit} iterations allowed: raise max_iterations",
            "time_limit": "it reached the time limit: raise time_limit or leave it unset",
        }.get(result.stop_reason, f"it stopped ({result.stop_reason or 'no reason given'})")
        out.append(
            QualityWarning(
                "not_converged",
                f"the solve did not converge after {result.iterations} iterations; {why}, "
                "(the guest may still move if run longer)",
                result.iterations,
                limit if result.stop_reason == "max_iterations" else None,
            )
        )
    opt = result.options
    kept = bool(getattr(opt, "smooth", False)) and getattr(opt, "smooth_mode", "") == "band"
    angle = getattr(opt, "join_angle", None)
    angled = any(angle) if isinstance(angle, tuple) else bool(angle)
    if kept and angled:
        # a crease was asked for: what counts is how far the guest is from it (a seam
        # left at its default, 0 or None in the per-seam list, by its crease itself)
        out += _join_angle_warning(m)
    else:
        out += _crease_warnings(m, kept)
    folds = _number(m, "folded_pairs")
    if folds is not None and folds > 0:
        out.append(
            QualityWarning(
                "folds",
                f"{int(folds)} pairs of adjacent guest faces folded over each other (their "
                "normals turned by more than 150°); the guest was pushed through itself: check "
                "the curves' direction and start, lower smooth_weight, or resample the guest",
                int(folds),
                0,
            )
        )
    weld = m.get("weld")
    if isinstance(weld, dict) and weld.get("ok") is False:
        out.append(
            QualityWarning(
                "weld_failed",
                f"host and guest could not be welded into one mesh ({weld.get('error', '')}); "
                "so there is no merged mesh and no self-intersection count: follow the weld "
                "error's advice, or save with merged=False to keep the guest and the report",
            )
        )
    pairs = _number(m, "self_intersections", "pairs")
    if pairs is not None and pairs > 0:
        si = m["self_intersections"]
        out.append(
            QualityWarning(
                "self_intersections",
                f"{int(pairs)} pairs of faces of the welded mesh intersect within "
                f"{si.get('rings')} rings of the seam (host-guest {si.get('host_guest')}, "
                f"guest-guest {si.get('guest_guest')}, host-host {si.get('host_host')})"
                + _where(si)
                + "; the guest passes through the host or itself there: check the curves' "
                "direction and which side the guest lies on, or lower smooth_weight (an "
                "end-to-side graft: a larger opening, a hood, see the seams page)",
                int(pairs),
                0,
            )
        )
    area = _area_warning(m)
    if area is not None:
        out.append(area)
    out.extend(curve_warnings(_curves(result)))
    return tuple(out)
