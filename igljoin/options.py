"""Options of a join: one frozen dataclass with documented defaults."""

from __future__ import annotations

import dataclasses
import functools
import sys
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from .errors import OptionsError

__all__ = ["JoinOptions", "MAX_ITERATIONS", "MAX_WEIGHT", "DEPRECATED", "new_names"]

#: Largest join angle, degrees: at 90° the guest would leave along the host's
#: normal, where the side it turns to is no longer defined.
MAX_JOIN_ANGLE = 89.0

#: Largest shape, stretch or smooth weight. The three terms are summed into one
#: quadratic form factored in float64 (16 significant digits): a weight 10^6
#: times the others already leaves the others at 1e-10 of the system, below the
#: solver's tolerance, and far larger weights make the factorization blame the
#: mesh (``shape_weight=1e308`` "converges" in 2 iterations with a 36° crease).
#: Only the ratios of the weights matter, so a larger range is never needed.
MAX_WEIGHT = 1e6
WEIGHT_RANGE_WHY = (
    "only the ratios of the weights matter, and beyond 1e6 the other terms fall below "
    "float64 rounding in the solve"
)
#: Key of the field metadata that marks an option as structural: changing it
#: changes the quadratic form of the global step, so
#: :meth:`igljoin.JoinSolver.update` factors the system again. Every field says
#: ``True`` or ``False`` (:meth:`JoinOptions.structural_fields` refuses a field
#: that says neither), so a new option cannot be forgotten.
STRUCTURAL = "structural"

#: Largest ``max_iterations`` (a few minutes of iterations on a paper-size join).
MAX_ITERATIONS = 1_000_000


#: Old option names still accepted, each with its new name. Each old name
#: was ``*tolerance`` in another unit; the new ones say which. They go in the
#: release after the one that renamed them.
DEPRECATED = {
    "tolerance": "energy_tolerance",
    "snap_tolerance": "snap_fraction",
    "smooth_tolerance": "smooth_keep_deg",
}

_HERE = str(Path(__file__).resolve().parent)


def _outside_igljoin() -> int:
    """``stacklevel`` of the first caller outside the igljoin package (for a warning)."""
    frame, level = sys._getframe(1), 1
    while frame is not None and str(Path(frame.f_code.co_filename).resolve()).startswith(_HERE):
        frame, level = frame.f_back, level + 1
    return level


def new_names(options: Mapping, where: str = "") -> dict:
    """``options`` with every deprecated name replaced by its new name.

    Parameters
    ----------
    options : mapping
        Option names to values, as given by the caller.
    where : str
        Prefix of the warning and error messages (e.g. ``"join.toml: [options]"``).

    Returns
    -------
    dict
        The same options under the current names (order kept).

    Warns
    -----
    DeprecationWarning
        For each old name used, naming the new one.

    Raises
    ------
    OptionsError
        If an old name and its new name are both given.

    Examples
    --------
    >>> import warnings
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     new_names({"tolerance": 1e-6, "smooth": False})
    {'energy_tolerance': 1e-06, 'smooth': False}
    """
    out = dict(options)
    if not any(old in out for old in DEPRECATED):
        return out
    prefix = f"{where} " if where else ""
    for old, new in DEPRECATED.items():
        if old not in out:
            continue
        if new in out:
            raise OptionsError(
                f"{prefix}{old} and {new} are the same option ({old} is its old name); "
                f"give only {new}"
            )
        warnings.warn(
            f"{prefix}the option {old} is now called {new}; the old name will be removed "
            "in the next release",
            DeprecationWarning,
            stacklevel=_outside_igljoin(),
        )
    return {DEPRECATED.get(k, k): v for k, v in out.items()}


def _accepts_old_names(cls: type) -> type:
    """Let the dataclass ``__init__`` of ``cls`` take the :data:`DEPRECATED` names too."""
    init = cls.__init__

    @functools.wraps(init)
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **new_names(kwargs))

    cls.__init__ = __init__
    return cls


def _structural(default: Any) -> Any:
    """A field whose change changes the quadratic form (a new factorization)."""
    return field(default=default, metadata={STRUCTURAL: True})


def _per_solve(default: Any) -> Any:
    """A field read by the iteration only (the factorization stays)."""
    return field(default=default, metadata={STRUCTURAL: False})


def _short(value: Any) -> str:
    """``repr`` of a value, cut to 60 characters (arrays and 400-digit integers stay short)."""
    text = repr(value)
    return text if len(text) <= 60 else f"{text[:40]}... ({len(text)} characters)"


def _default(name: str) -> Any:
    """The default value of the option ``name`` (for an error message)."""
    return next(f.default for f in fields(JoinOptions) if f.name == name)


@_accepts_old_names
@dataclass(frozen=True)
class JoinOptions:
    """Weights and solver settings of a join.

    Parameters
    ----------
    smooth : bool
        Include the smooth-join term (paper §4.4). ``False`` gives the
        paper's "without smooth join" variant. The term is in the energy only
        when ``smooth`` is true *and* ``smooth_weight > 0``: either switch
        turns it off, whatever the other says.
    shape_weight : float
        ``w_L``, weight of the Laplacian shape term (Eq. 4).
    stretch_weight : float
        Multiplier of the stiffness ``k_ij`` of the stretch term (Eq. 5–6).
    smooth_weight : float
        ``w_J``, weight of the smooth-join term (Eq. 7). Each of the three
        weights is 0 or at most :data:`MAX_WEIGHT` (1e6): only their ratios
        matter, and beyond that the other terms fall below float64 rounding.
    smooth_mode : {"band", "robust", "paper"}
        ``"band"`` (default) pulls the direction in which the guest leaves
        each seam vertex, fitted over a band of width ``smooth_band``
        (:mod:`igljoin.bandfit`), into the host's tangent half-plane
        continued across the seam, fitted over the same band: slivers,
        very short seam edges and zig-zag seams change neither.
        ``"robust"`` pulls every one-ring cross-seam edge into the host's
        tangent plane; ``"paper"`` pulls one tangential point per seam
        vertex to a fixed target (Eq. 7 literally).
    smooth_band : float, optional
        Band width in mesh units for ``smooth_mode="band"`` and for the
        crease measure. ``None`` (default): 3 median edge lengths of the
        coarser side near the seam (:func:`igljoin.crease.default_band`).
    smooth_radius : float
        Host tangent planes: 0 (default) takes them from the faces at each
        host curve vertex, as the paper does; a positive value fits a
        quadric to the host vertices within that many mean host seam edges
        instead, which follows the underlying surface rather than its noise.
    join_angle : float or sequence of float, optional
        Band mode: the angle in degrees (0 to 89) at which the guest leaves
        the host, measured from the host's tangent plane continued across the
        seam — 0 is the paper's smooth join, an end-to-side graft leaves its
        vessel at 25–45°. One value for every seam, or one per seam (``None``
        in a list keeps that seam's default). Default ``None``, the same as 0:
        the smooth join. Either way the join removes the part of the crease
        that is coherent along the seam and deviates significantly from the
        angle asked for (:mod:`igljoin.band_targets`).
    join_side : {"guest", "normal", "opposite"}
        Towards which side of the host surface a positive ``join_angle``
        turns: the side the rest guest lies on (default), the side of the
        host's normal, or the other.
    smooth_keep_deg : float, optional
        Robust and band modes: crease in degrees that the join keeps, i.e.
        below which a cross-seam edge is left alone (formerly
        ``smooth_tolerance``). ``None`` (default) is 0 with one-ring tangent
        planes and, with ``smooth_radius > 0``, the host's own normal noise
        (median angle between its one-ring and fitted cross-seam
        directions), so the join does not chase scan noise.
    laplacian : {"uniform", "cotangent"}
        Laplacian weights; uniform (``1/|N(p)|``) as in the paper.
    rotation_aware : bool
        Rotate Laplacian coordinates by per-vertex rotations fitted in the
        local step, so a guest that arrives rotated is not penalised.
        ``False`` is the paper's fixed Laplacian.
    stiffness : array_like, shape (n,) or (m,), optional
        Relative stiffness ``k_ij`` (1 = default tissue) per guest vertex or
        face; edges take the mean of their vertices or faces.
    stiffness_on : {"auto", "vertex", "face"}
        Whether ``stiffness`` is per vertex or per face (``"auto"`` decides
        by its length; required when the guest has as many faces as vertices).
    max_iterations : int
        Upper bound on local/global iterations (default 2000, at most
        :data:`MAX_ITERATIONS`, 1,000,000).
    energy_tolerance : float
        Relative energy change at which the iteration stops (formerly
        ``tolerance``): converged when the energy fell by less than
        ``energy_tolerance`` times its value over the last five iterations,
        or the fall still to come at the slowest rate of the last three
        iterations (from the fourth on, each step taken whole; docs/method.md)
        is below half that, and the last iteration moved no
        vertex by more than ``sqrt(energy_tolerance)`` mean edge lengths
        (or the energy is below
        ``energy_tolerance²`` of its scale, a minimum of zero energy). The
        default 1e-7 leaves the energy within about 1e-6 (relative) of the
        minimum the iteration converges to.
    time_limit : float, optional
        Seconds after which the solve returns its current, non-converged result.
    snap_fraction : float
        Host points closer than this fraction of a guest edge to a guest
        vertex (in arc length) are matched to it instead of being inserted
        (formerly ``snap_tolerance``).
    initial_guess : {"extend", "rigid"}
        Start from the rigidly aligned guest with the seam displacement
        smoothly extended (default), or from the rigidly aligned guest alone.
    acceleration : int
        History length of the quasi-Newton (L-BFGS) acceleration of the
        local/global iteration (0 = plain iteration). Its initial Hessian is
        the factored quadratic form, so its first step is the plain step, and
        a line search accepts only steps that lower the energy: it converges
        to the same minimum as the plain iteration, in far fewer iterations.
    preconditioner : {"auto", "factored", "two-level"}
        Initial inverse Hessian of the quasi-Newton steps (the answers are
        the same minimum; only the iteration count and time differ).
        ``"factored"``: the factored quadratic form ``P`` alone.
        ``"two-level"``: ``P`` with a coarse correction that knows the
        rotation (bending) modes — the Gauss–Newton model on the rigid
        motions of clusters of about 20 vertices
        (:class:`igljoin.twolevel.TwoLevelModel`), built and factored at the
        start of every solve: on patch-like guests of 10,000 vertices and
        more 2–3× fewer iterations (46 / 75 against 100 / 248 at 10k /
        100k), on long tubes none fewer, and below a few thousand vertices
        its set-up costs more than it saves. ``"auto"`` (default):
        ``"factored"`` below :data:`igljoin.twolevel.AUTO_FROM_VERTICES`
        (20,000) free guest vertices, and from there the coarse correction
        with three bending motions per cluster as well, rebuilt at the
        current positions whenever the guest has turned 0.2 rad
        (:data:`igljoin.twolevel.AUTO_MODEL`; a flat cluster too small for
        its bending motions, fewer than six vertices, keeps its rigid ones:
        :data:`igljoin.twolevel.SPANNED_BENDING`): fewer iterations on tubes
        too (203 / 230 against 486 / 746 at 40k / 100k) and less time on
        tubes and patches from 20k on (0.4–0.96 × ``P``'s iteration;
        docs/limits.md). The coarse corrections precondition the
        quasi-Newton steps: with ``acceleration=0`` ``"auto"`` is the
        factored form and ``"two-level"`` is refused; ``"auto"`` is the
        factored form as well when the coarse model would
        hold more than :data:`igljoin.twolevel.AUTO_MAX_MODEL_ENTRIES`
        entries (counted before it is built; past that size it was
        measured not to pay) or when its coarse system cannot be factored
        soundly (its ``fallback`` says why), and ``"two-level"`` is refused
        with an ``OptionsError`` past
        :data:`igljoin.twolevel.MAX_MODEL_ENTRIES`. The additive coarse
        correction is solved on a second thread while the fine back-solve
        runs, from :data:`igljoin.twolevel.CONCURRENT_FROM_VERTICES` free
        vertices (the same result; on two free cores the 100k patch's
        back-solves took 0.7× the time, the 24k patch's and tube's whole
        joins 0.89× and 0.88×).
    linear_solver : {"auto", "igl", "cholespy", "pardiso"}
        Sparse Cholesky backend of the global step: libigl's
        ``min_quad_with_fixed`` (always available), cholespy (the
        ``igljoin[fast]`` extra, several times faster back-substitutions) or
        MKL Pardiso (the ``igljoin[pardiso]`` extra, a supernodal
        factorization several times faster on large or dense systems).
        ``"auto"`` (default) uses Pardiso from
        :data:`igljoin.linsolve.PARDISO_FROM_NNZ` nonzeros on (about 55k
        guest vertices) and cholespy below, each when installed. Results
        agree to rounding.

    Notes
    -----
    The old names ``tolerance``, ``snap_tolerance`` and ``smooth_tolerance``
    (:data:`DEPRECATED`) are still accepted, with a ``DeprecationWarning``,
    for one release.
    """

    smooth: bool = _structural(True)
    shape_weight: float = _structural(1.0)
    stretch_weight: float = _structural(1.0)
    smooth_weight: float = _structural(10.0)
    smooth_mode: str = _structural("band")
    smooth_band: float | None = _structural(None)
    smooth_radius: float = _structural(0.0)
    smooth_keep_deg: float | None = _structural(None)
    join_angle: Any = _structural(None)
    join_side: str = _structural("guest")
    laplacian: str = _structural("uniform")
    rotation_aware: bool = _structural(True)
    stiffness: Any = _structural(None)
    stiffness_on: str = _structural("auto")
    max_iterations: int = _per_solve(2000)
    energy_tolerance: float = _per_solve(1e-7)
    time_limit: float | None = _per_solve(None)
    snap_fraction: float = _structural(0.1)
    initial_guess: str = _per_solve("extend")
    acceleration: int = _per_solve(10)
    preconditioner: str = _per_solve("auto")
    linear_solver: str = _structural("auto")

    def __post_init__(self) -> None:
        for name in ("shape_weight", "stretch_weight", "smooth_weight"):
            self._number(name, low=0.0, high=MAX_WEIGHT)
        self._number("smooth_radius", low=0.0)
        if self.shape_weight == 0 and self.stretch_weight == 0:
            raise OptionsError(
                "shape_weight and stretch_weight are both 0: nothing holds the guest's shape; "
                "make at least one positive"
            )
        self._number("energy_tolerance", low=0.0, strict=True)
        self._number("snap_fraction", low=0.0)
        if self.snap_fraction >= 0.5:
            raise OptionsError(
                f"snap_fraction={self.snap_fraction} must be below 0.5 (a fraction of a guest "
                "edge); try the default 0.1"
            )
        self._join_angle()
        if self.smooth_band is not None:
            self._number("smooth_band", low=0.0, strict=True)
        if self.smooth_keep_deg is not None:
            self._number("smooth_keep_deg", low=0.0)
            if self.smooth_keep_deg >= 90.0:
                raise OptionsError(
                    f"smooth_keep_deg={self.smooth_keep_deg} must be below 90 degrees; "
                    "leave it unset for the automatic value"
                )
        if self.time_limit is not None:
            self._number("time_limit", low=0.0, strict=True)
        acc = self.acceleration
        if isinstance(acc, bool) or not isinstance(acc, (int, np.integer)) or not 0 <= acc <= 50:
            raise OptionsError(
                f"acceleration={_short(acc)} must be an integer from 0 to 50 (the default is "
                f"{_default('acceleration')})"
            )
        if self.preconditioner == "two-level" and acc == 0:
            raise OptionsError(
                "preconditioner='two-level' preconditions the quasi-Newton steps, which "
                "acceleration=0 turns off; give acceleration > 0 (the default is "
                f"{_default('acceleration')}) or give preconditioner='factored' or 'auto'"
            )
        it = self.max_iterations
        if (
            isinstance(it, bool)
            or not isinstance(it, (int, np.integer))
            or not 1 <= it <= MAX_ITERATIONS
        ):
            raise OptionsError(
                f"max_iterations={_short(it)} must be an integer from 1 to {MAX_ITERATIONS:,} "
                f"(the default is {_default('max_iterations')})"
            )
        for name, allowed in (
            ("smooth_mode", ("band", "robust", "paper")),
            ("join_side", ("guest", "normal", "opposite")),
            ("laplacian", ("uniform", "cotangent")),
            ("stiffness_on", ("auto", "vertex", "face")),
            ("initial_guess", ("extend", "rigid")),
            ("preconditioner", ("factored", "two-level", "auto")),
            ("linear_solver", ("auto", "igl", "cholespy", "pardiso")),
        ):
            value = getattr(self, name)
            if not isinstance(value, str) or value not in allowed:
                raise OptionsError(
                    f"{name}={_short(value)} is not one of {', '.join(map(repr, allowed))}"
                    + ("" if isinstance(value, str) else " (give one string)")
                )
            object.__setattr__(self, name, str(value))
        for name in ("smooth", "rotation_aware"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise OptionsError(f"{name}={getattr(self, name)!r} must be True or False")
            object.__setattr__(self, name, bool(getattr(self, name)))
        for name in ("max_iterations", "acceleration"):
            object.__setattr__(self, name, int(getattr(self, name)))
        if self.stiffness is not None:
            try:
                k = np.asarray(self.stiffness, dtype=np.float64)
            except (TypeError, ValueError, OverflowError):
                k = np.zeros(0)
            if k.ndim != 1 or k.size == 0 or not np.isfinite(k).all() or (k <= 0).any():
                raise OptionsError(
                    "stiffness must be a 1-D array of positive finite numbers (one per guest "
                    "vertex or face, 1 = default tissue)"
                )
            object.__setattr__(self, "stiffness", k)

    def _join_angle(self) -> None:
        """Check ``join_angle`` (None, a number, or one number or None per seam)."""
        value = self.join_angle
        if value is None:
            return
        many = isinstance(value, (list, tuple, np.ndarray))
        values = list(value) if many else [value]
        out = []
        for v in values:
            ok = v is None or (
                isinstance(v, (int, float, np.integer, np.floating))
                and not isinstance(v, bool)
                and np.isfinite(float(v))
                and 0.0 <= float(v) <= MAX_JOIN_ANGLE
            )
            if not ok:
                raise OptionsError(
                    f"join_angle={_short(value)} must be a number of degrees from 0 to "
                    f"{MAX_JOIN_ANGLE:g} (the angle the guest leaves the host at), one per "
                    "seam, or None for the default smooth join"
                )
            out.append(None if v is None else float(v))
        if many and not out:
            raise OptionsError("join_angle=[] is empty; give one angle per seam or None")
        object.__setattr__(self, "join_angle", tuple(out) if many else out[0])

    def _number(
        self, name: str, low: float, strict: bool = False, high: float | None = None
    ) -> None:
        value = getattr(self, name)
        ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
            value, bool
        )
        if ok:
            try:
                value = float(value)
            except OverflowError:  # an integer beyond float range (10**400)
                ok = False
        if ok:
            ok = np.isfinite(value) and (value > low if strict else value >= low)
            ok = ok and (high is None or value <= high)
        if not ok:
            bound = f"> {low:g}" if strict else f">= {low:g}"
            if high is not None:
                bound = f"from {low:g} to {high:g}"
            raise OptionsError(
                f"{name}={_short(getattr(self, name))} is out of range; it must be a finite "
                f"number {bound} (the default is {_default(name)})"
                + (f"; {WEIGHT_RANGE_WHY}" if high is not None else "")
            )
        object.__setattr__(self, name, value)

    @classmethod
    def structural_fields(cls) -> tuple[str, ...]:
        """Names of the options whose change needs a new factorization.

        Read from the fields' metadata (``metadata={"structural": ...}``).

        Returns
        -------
        tuple of str
            In field order.

        Raises
        ------
        TypeError
            If a field does not say whether it is structural (a programming
            error in a new option, not a user error).

        Examples
        --------
        >>> "shape_weight" in JoinOptions.structural_fields()
        True
        >>> "max_iterations" in JoinOptions.structural_fields()
        False
        """
        unmarked = [f.name for f in fields(cls) if STRUCTURAL not in f.metadata]
        if unmarked:
            raise TypeError(
                f"JoinOptions fields {unmarked} do not say whether they are structural; "
                "declare them with _structural(...) or _per_solve(...)"
            )
        return tuple(f.name for f in fields(cls) if f.metadata[STRUCTURAL])

    @classmethod
    def make(cls, options: JoinOptions | dict | None = None, **overrides: Any) -> JoinOptions:
        """Build options from an instance or mapping plus keyword overrides.

        An instance without overrides is returned as it is: it validated
        itself when it was built and is frozen, so it is not checked again.
        """
        if isinstance(options, cls) and not overrides:
            return options
        names = {f.name for f in fields(cls)}
        base = (
            {}
            if options is None
            else (
                dataclasses.asdict(options)
                if isinstance(options, JoinOptions)
                else new_names(options)
            )
        )
        merged = {**base, **new_names(overrides)}
        unknown = sorted(set(merged) - names)
        if unknown:
            raise OptionsError(
                f"unknown join options {unknown}; valid options are {', '.join(sorted(names))}"
            )
        return cls(**merged)

    def replace(self, **changes: Any) -> JoinOptions:
        """A copy with some options changed (validated)."""
        return JoinOptions.make(self, **changes)

    def to_json(self) -> dict:
        """Options as plain JSON values (stiffness summarised)."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                v = {"count": int(v.size), "min": float(v.min()), "max": float(v.max())}
            out[f.name] = v
        return out
