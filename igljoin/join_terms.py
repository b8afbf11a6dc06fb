"""The paper's §4.2–4.4 for one join: its energy terms, built from its options.

Shape (§4.2) and stretch (§4.3) terms are over the refined guest; each seam
adds a smooth-join term (§4.4): against the host's band-fitted tangent planes
tilted by the crease the join keeps (``smooth_mode="band"``,
:mod:`igljoin.band_targets`), or against the host's cross-seam frames
(``"paper"``: one-ring; ``"robust"``: smoothed over a radius).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import band_targets
from .bandfit import BandFit
from .boundary import SelectedCurve
from .correspond import Correspondence
from .crease import default_band
from .errors import OptionsError
from .frames import SeamFrames, seam_frames, unit
from .host_values import HostValues
from .mesh import Mesh
from .options import JoinOptions
from .polyline import mean_segment
from .seam_geometry import SeamGeometry
from .stiffness import refined_stiffness
from .terms import (
    ShapeTerm,
    SmoothJoinTerm,
    StretchTerm,
    Term,
    check_order,
    difference_operators,
    edge_stiffness,
)

__all__ = [
    "JoinTerms",
    "TermInputs",
    "TERMS",
    "build_terms",
    "join_angles",
    "seam_bands",
    "interpolate_frames",
]


@dataclass
class JoinTerms:
    """The terms of a join and what building them found.

    Attributes
    ----------
    terms : list of Term
        Shape, stretch, then one smooth-join term per seam (each if its
        weight is positive).
    crease_removed : list of ndarray
        Per band smooth-join term, shape (s,): the crease (degrees) it
        removes at each seam vertex (empty for the other modes).
    """

    terms: list[Term]
    crease_removed: list[np.ndarray]


def _at_points(A: np.ndarray, edge: np.ndarray, t: np.ndarray, closed: bool) -> np.ndarray:
    """Per-vertex values ``A`` (k, ...) of a curve, linearly interpolated at points on its edges.

    ``edge`` (s,) is each point's curve edge (from vertex ``edge`` to the
    next), ``t`` (s,) its position along it in ``[0, 1]``; returns (s, ...).
    """
    k = len(A)
    nxt = (edge + 1) % k if closed else np.minimum(edge + 1, k - 1)
    w = t.reshape(-1, *([1] * (A.ndim - 1)))
    return A[edge] * (1.0 - w) + A[nxt] * w


def interpolate_frames(
    frames: SeamFrames, edge: np.ndarray, t: np.ndarray, closed: bool
) -> SeamFrames:
    """Frames along a curve at points on its edges, interpolated and made orthonormal.

    Parameters
    ----------
    frames : SeamFrames
        At the curve's ``k`` vertices.
    edge : ndarray of int64, shape (s,)
        Curve edge of each point (from vertex ``edge`` to the next).
    t : ndarray, shape (s,)
        Position of each point along its edge, in ``[0, 1]``.
    closed : bool

    Returns
    -------
    SeamFrames
        Shape (s, 3) each.
    """

    def lerp(A):
        return unit(_at_points(A, edge, t, closed))

    normal = lerp(frames.normal)
    inward = lerp(frames.inward)
    inward = unit(inward - np.einsum("ij,ij->i", inward, normal)[:, None] * normal)
    return SeamFrames(normal=normal, tangent=lerp(frames.tangent), inward=inward)


def join_angles(options: JoinOptions, k: int) -> list:
    """``join_angle`` per seam of ``k`` (None: the default smooth join).

    Parameters
    ----------
    options : JoinOptions
    k : int
        Number of seams.

    Returns
    -------
    list of float or None
        ``k`` angles in degrees.

    Raises
    ------
    OptionsError
        If ``join_angle`` is a list whose length is not ``k``.
    """
    angle = options.join_angle
    if not isinstance(angle, tuple):
        return [angle] * k
    if len(angle) != k:
        raise OptionsError(
            f"join_angle has {len(angle)} values for {k} seam{'s' if k != 1 else ''}; "
            "give one per seam (None keeps a seam's default) or a single angle"
        )
    return list(angle)


def seam_bands(
    options: JoinOptions, host: Mesh, corr: Correspondence, curves: list, parts: list
) -> list[float]:
    """The band width of each seam: ``smooth_band``, else :func:`igljoin.crease.default_band`.

    Parameters
    ----------
    options : JoinOptions
    host : Mesh
    corr : Correspondence
        Of all seams (the refined guest).
    curves : list of SelectedCurve
        The host curve of each seam.
    parts : list of Correspondence
        Each seam's own correspondence.

    Returns
    -------
    list of float
        One band width per seam, in mesh units.
    """
    return [
        options.smooth_band
        or default_band(
            SeamGeometry(
                host.V, host.F, hc.indices, corr.V, corr.F, part.seam[part.host_hit], hc.closed
            ),
            guest_curve=part.seam,
        )
        for hc, part in zip(curves, parts)
    ]


def _band_term(
    options: JoinOptions,
    corr: Correspondence,
    part: Correspondence,
    curve: SelectedCurve,
    host: Mesh,
    host_values: HostValues,
    band: float,
    angle: float | None,
    rest_fit: Callable[[np.ndarray, bool, float], BandFit],
) -> tuple[SmoothJoinTerm, np.ndarray]:
    """The band smooth-join term of one seam and the crease it removes (degrees, shape (s,)).

    The host's band-fitted tangent planes at the seam targets are tilted by
    the elevation the join keeps (the rest guest's, less the crease coherent
    along the seam), and the guest's band-fitted direction off each seam
    vertex is pulled into them. ``smooth_keep_deg`` widens that into a wedge.
    """
    host_fit = host_values.band_fit(curve, band)
    edge, t = part.host_edge, part.host_edge_t
    at_seam = interpolate_frames(host_fit.frames, edge, t, curve.closed)
    guest_fit = rest_fit(part.seam, curve.closed, band)
    targets = _at_points(host.V[curve.indices], edge, t, curve.closed)
    host_se = _at_points(host_fit.slope_error, edge, t, curve.closed)
    kept, removed = band_targets.kept_elevation(
        at_seam,
        guest_fit.frames.inward,
        corr.V[part.seam],
        targets,
        np.hypot(host_se, guest_fit.slope_error),
        curve.closed,
        band,
        join_angle=angle,
        join_side=options.join_side,
    )
    term = SmoothJoinTerm(
        corr.V,
        corr.F,
        part.seam,
        band_targets.tilted_frames(at_seam, kept),
        options.smooth_weight,
        "band",
        np.radians(float(options.smooth_keep_deg or 0.0)),
        fit=guest_fit,
    )
    return term, np.degrees(np.abs(removed))


def _smooth_keep_deg(
    options: JoinOptions, host: Mesh, smoothed: SeamFrames, curve: SelectedCurve
) -> float:
    """Crease (degrees) the robust smooth join tolerates: the host's own normal noise.

    The median angle between the host's one-ring and smoothed cross-seam
    directions along ``curve``, unless ``smooth_keep_deg`` is given.
    """
    opt = options
    if opt.smooth_mode == "paper" or (opt.smooth_keep_deg is None and opt.smooth_radius == 0):
        return 0.0
    if opt.smooth_keep_deg is not None:
        return float(opt.smooth_keep_deg)
    onering = seam_frames(host.V, host.F, curve.indices, curve.closed)
    cos = np.clip(np.einsum("ij,ij->i", onering.inward, smoothed.inward), -1.0, 1.0)
    return float(np.degrees(np.median(np.arccos(cos))))


def _frame_term(
    options: JoinOptions,
    corr: Correspondence,
    part: Correspondence,
    curve: SelectedCurve,
    host: Mesh,
) -> SmoothJoinTerm:
    """The paper's or the robust smooth-join term of one seam."""
    opt = options
    mean_edge = mean_segment(host.V[curve.indices], curve.closed)
    radius = None if opt.smooth_mode == "paper" else opt.smooth_radius * mean_edge
    radius = radius or None
    frames = seam_frames(host.V, host.F, curve.indices, curve.closed, radius=radius)
    at_seam = interpolate_frames(frames, part.host_edge, part.host_edge_t, curve.closed)
    return SmoothJoinTerm(
        corr.V,
        corr.F,
        part.seam,
        at_seam,
        opt.smooth_weight,
        opt.smooth_mode,
        np.radians(_smooth_keep_deg(opt, host, frames, curve)),
    )


@dataclass(frozen=True)
class TermInputs:
    """What the term builders of :data:`TERMS` read.

    Attributes
    ----------
    options : JoinOptions
    corr : Correspondence
        Of all seams: the refined rest guest ``corr.V, corr.F``.
    E : ndarray of int64, shape (e, 2)
        Its unique edges.
    guest : Mesh
        The guest as given (its counts place a stiffness map).
    host : Mesh
        The (combined) host.
    host_values : HostValues
        The host's kept values (band fits).
    curves : list of SelectedCurve
        The host curve of each seam.
    parts : list of Correspondence
        Each seam's own correspondence.
    bands : list of float
        Each seam's band width (:func:`seam_bands`).
    rest_fit : callable
        ``rest_fit(curve, closed, band)``: the rest guest's band fit along
        ``curve`` (``band_fit(corr.V, corr.F, curve, closed, band)``), from the
        store the solver's measures share where they made it (else made and
        not kept: :meth:`igljoin.measure_join.RestMeasures.fit`).
    """

    options: JoinOptions
    corr: Correspondence
    E: np.ndarray
    guest: Mesh
    host: Mesh
    host_values: HostValues
    curves: list
    parts: list
    bands: list
    rest_fit: Callable[[np.ndarray, bool, float], BandFit]

    @functools.cached_property
    def differences(self) -> tuple:
        """``E``'s difference operator and its transpose (n = ``corr.V``'s vertices), made
        on first use and shared by the shape and stretch terms (at 1M guest vertices one
        pair holds 0.16 GB): :func:`igljoin.terms.difference_operators`."""
        return difference_operators(self.E, len(self.corr.V))


def _shape_terms(inputs: TermInputs) -> list[tuple[Term, np.ndarray | None]]:
    """§4.2: the (rotation-aware) Laplacian shape term."""
    opt, c = inputs.options, inputs.corr
    differences = inputs.differences if opt.rotation_aware else None
    term = ShapeTerm(
        c.V, c.F, opt.shape_weight, opt.laplacian, opt.rotation_aware, E=inputs.E,
        differences=differences,
    )  # fmt: skip
    return [(term, None)]


def _stretch_terms(inputs: TermInputs) -> list[tuple[Term, np.ndarray | None]]:
    """§4.3: minimum stretching with the edge stiffness ``k_ij``."""
    opt, c, guest = inputs.options, inputs.corr, inputs.guest
    k = edge_stiffness(inputs.E, c.F, *refined_stiffness(opt, guest.n_vertices, guest.n_faces, c))
    term = StretchTerm(c.V, inputs.E, opt.stretch_weight * k, differences=inputs.differences)
    return [(term, None)]


def _smooth_terms(inputs: TermInputs) -> list[tuple[Term, np.ndarray | None]]:
    """§4.4: one smooth-join term per seam (band, paper or robust), if ``smooth`` is on."""
    opt, c = inputs.options, inputs.corr
    seams = list(zip(inputs.curves, inputs.parts))
    if not opt.smooth:
        return []
    if opt.smooth_mode != "band":
        return [(_frame_term(opt, c, part, hc, inputs.host), None) for hc, part in seams]
    angles = join_angles(opt, len(seams))
    return [
        _band_term(opt, c, part, hc, inputs.host, inputs.host_values, band, angle, inputs.rest_fit)
        for (hc, part), band, angle in zip(seams, inputs.bands, angles)
    ]


#: The terms of a join, in the order their local steps run, each built when the
#: weight option beside it is positive. A new term is one class in
#: :mod:`igljoin.terms`, one weight in :class:`~igljoin.options.JoinOptions` and
#: one row here. Order matters where a term reads what another's local step
#: sets: the stretch term reads the rotations the shape term fits
#: (:attr:`igljoin.terms.Term.reads_rotations`), so the shape term comes first;
#: :func:`igljoin.terms.check_order` refuses a list that breaks this.
TERMS = (
    ("shape_weight", _shape_terms),
    ("stretch_weight", _stretch_terms),
    ("smooth_weight", _smooth_terms),
)


def build_terms(inputs: TermInputs) -> JoinTerms:
    """The terms of a join (§4.2–4.4) over its refined guest, in the order of :data:`TERMS`.

    Parameters
    ----------
    inputs : TermInputs

    Returns
    -------
    JoinTerms
    """
    built = [
        made
        for weight, make in TERMS
        if getattr(inputs.options, weight) > 0
        for made in make(inputs)
    ]
    terms = [term for term, _ in built]
    check_order(terms)
    shape = [t for t in terms if isinstance(t, ShapeTerm) and t.rotation_aware]
    if shape:
        for term in terms:
            if isinstance(term, StretchTerm):
                term.share_rest(shape[0].rest_edges)
    return JoinTerms(terms, [removed for _, removed in built if removed is not None])
