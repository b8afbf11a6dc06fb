"""Colour scales of the inspection views (NumPy only, no polyscope).

Area change is shown on the paper's scale — white where a triangle kept its
area, dark red where it changed a lot (§5, Figs. 2–3) — extended to tell
shrinking from stretching: the scale is diverging and symmetric in
``log2(area ratio)``, blue for shrink, white at ratio 1, red for stretch, and
saturates at ``limit`` (stretch) and ``1 / limit`` (shrink). The control
colours are ColorBrewer's RdBu with a pure-white centre.
"""

from __future__ import annotations

import numpy as np

from ..errors import OptionsError

__all__ = [
    "AREA_RATIO_LIMIT",
    "BACKGROUND",
    "HOST_COLOR",
    "NAN_COLOR",
    "area_colors",
    "area_scale",
    "area_ticks",
    "diverging",
    "magnitude_colors",
]

#: Area ratio drawn at full colour (its inverse for shrink): 1.5 x (2/3 of) the rest area is
#: a large change for tissue, and the paper's samples (up to ~1.4 x) then span most of the scale.
AREA_RATIO_LIMIT = 1.5

#: Control colours of the diverging scale from -1 (dark blue) through 0 (white) to +1 (dark red).
_RDBU = (
    np.array(
        [
            [5, 48, 97],
            [33, 102, 172],
            [67, 147, 195],
            [146, 197, 222],
            [209, 229, 240],
            [255, 255, 255],
            [253, 219, 199],
            [244, 165, 130],
            [214, 96, 77],
            [178, 24, 43],
            [103, 0, 31],
        ],
        dtype=np.float64,
    )
    / 255.0
)

#: Scene colours (RGB in [0, 1]); none of them is on the blue-white-red scale.
BACKGROUND = (0.16, 0.17, 0.19)
HOST_COLOR = (0.55, 0.68, 0.52)
REST_COLOR = (0.75, 0.75, 0.78)
SEAM_COLOR = (1.0, 0.82, 0.1)
HOST_TANGENT_COLOR = (0.1, 0.85, 0.35)
GUEST_TANGENT_COLOR = (0.9, 0.25, 0.9)
MERGED_COLOR = (0.85, 0.8, 0.7)
#: Faces whose ratio is undefined (zero rest area).
NAN_COLOR = (0.5, 0.5, 0.5)


def polyscope_background(rgb: tuple) -> tuple:
    """Value to give ``polyscope.set_background_color`` so that it renders as sRGB ``rgb``.

    Polyscope tone-maps the background (measured: ``out = min(1, (v / 0.9) ** (1 / 2.2))``)
    but not surface colours; this inverts that map.
    """
    return tuple(0.9 * float(c) ** 2.2 for c in rgb)


def diverging(t: np.ndarray) -> np.ndarray:
    """Blue-white-red colours of values ``t`` in [-1, 1] (clipped), shape (k,) -> (k, 3).

    -1 is dark blue, 0 white, +1 dark red; non-finite values get :data:`NAN_COLOR`.

    Examples
    --------
    >>> diverging(np.array([0.0])).tolist()
    [[1.0, 1.0, 1.0]]
    """
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    bad = ~np.isfinite(t)
    s = (np.clip(np.where(bad, 0.0, t), -1.0, 1.0) + 1.0) * 0.5 * (len(_RDBU) - 1)
    lo = np.minimum(np.floor(s).astype(np.int64), len(_RDBU) - 2)
    f = (s - lo)[:, None]
    out = _RDBU[lo] * (1.0 - f) + _RDBU[lo + 1] * f
    out[bad] = NAN_COLOR
    return out


def area_scale(ratio: np.ndarray, limit: float = AREA_RATIO_LIMIT) -> np.ndarray:
    """Position of area ratios on the colour scale: ``log2(ratio) / log2(limit)``, shape (m,).

    0 is no change, +1 the limit (stretch), -1 its inverse (shrink); values
    beyond are drawn at full colour, a collapsed face (ratio 0) is -1 and an
    undefined ratio stays ``nan``.
    """
    if not (np.isfinite(limit) and limit > 1.0):
        raise OptionsError(f"limit={limit!r} must be a finite area ratio > 1 (the default is 1.5)")
    r = np.asarray(ratio, dtype=np.float64).reshape(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.log2(np.where(r > 0, r, 1.0)) / np.log2(limit)
    # a collapsed face (ratio 0) is full shrink; an undefined ratio (nan) stays undefined
    return np.where(r > 0, t, np.where(r == 0, -1.0, np.nan))


def area_colors(ratio: np.ndarray, limit: float = AREA_RATIO_LIMIT) -> np.ndarray:
    """Colours of area ratios: blue shrink, white unchanged, red stretch.

    Parameters
    ----------
    ratio : ndarray, shape (m,)
        Deformed over rest area per face.
    limit : float
        Ratio shown at full red (``1 / limit`` at full blue); symmetric in log ratio.

    Returns
    -------
    ndarray, shape (m, 3)
        RGB in [0, 1].

    Examples
    --------
    >>> area_colors(np.array([1.0, 2.0, 0.5]), limit=2.0).round(3).tolist()
    [[1.0, 1.0, 1.0], [0.404, 0.0, 0.122], [0.02, 0.188, 0.38]]
    """
    return diverging(area_scale(ratio, limit))


def magnitude_colors(ratio: np.ndarray, limit: float = AREA_RATIO_LIMIT) -> np.ndarray:
    """The paper's scale: white for no area change, dark red for a large one (either sign).

    Parameters
    ----------
    ratio : ndarray, shape (m,)
    limit : float
        Ratio (or its inverse) shown at full dark red.

    Returns
    -------
    ndarray, shape (m, 3)
    """
    return diverging(np.abs(area_scale(ratio, limit)))


def area_ticks(limit: float = AREA_RATIO_LIMIT) -> tuple[np.ndarray, np.ndarray]:
    """Tick positions in [-1, 1] and the area ratios they stand for, shape (5,) each."""
    t = np.array([-1.0, -0.5, 0.0, 0.5, 1.0])
    return t, np.exp2(t * np.log2(limit))
