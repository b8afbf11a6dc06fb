"""Tissue stiffness maps for the stretch term: from regions or from a mesh attribute.

The stretch term (paper Eq. 5–6) weighs each guest edge by a stiffness
``k_ij``. It is *relative*: 1 is the default tissue, 10 resists stretching
and compression ten times as much, 0.1 a tenth as much. The value has no
physical unit; only ratios between regions matter (together with
``stretch_weight`` against the shape and smooth-join terms).

A join takes the stiffness as

* an array, one value per guest vertex or face (``stiffness=k``; edges take
  the mean of their two vertices or of their one or two faces),
* the name of a per-vertex or per-face attribute of the guest mesh
  (``stiffness="name"``, e.g. a scalar property of a PLY file read with
  :func:`igljoin.read_mesh`), resolved by :func:`stiffness_from_attribute`,
* regions of guest vertices (``stiffness_regions=[(vertices, k), ...]``),
  turned into a per-vertex array by :func:`stiffness_from_regions`.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from .correspond import Correspondence
from .errors import OptionsError
from .mesh import Mesh
from .options import JoinOptions

__all__ = [
    "stiffness_from_regions",
    "stiffness_from_attribute",
    "needs_guest",
    "resolve_stiffness",
    "refined_stiffness",
]


def _positive(value: Any, what: str) -> float:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not ok or not np.isfinite(value) or value <= 0:
        raise OptionsError(
            f"{what}={value!r} must be a positive finite number (relative stiffness, 1 = default "
            "tissue)"
        )
    return float(value)


def stiffness_from_regions(
    n: int, regions: Iterable[tuple[Any, float]], default: float = 1.0
) -> np.ndarray:
    """Per-vertex relative stiffness from regions of vertices.

    Parameters
    ----------
    n : int
        Number of guest vertices.
    regions : iterable of (vertices, k)
        ``vertices`` is an array of vertex indices (shape (r,)) or a boolean
        mask (shape (n,)); ``k`` is the region's stiffness relative to the
        default tissue (1). Where regions overlap, the later one wins.
    default : float
        Stiffness of vertices in no region.

    Returns
    -------
    ndarray, shape (n,)
        Positive values; pass as ``stiffness=`` (per vertex) to
        :func:`igljoin.join`.

    Raises
    ------
    OptionsError
        A region is not a pair, names a vertex out of range, or has a
        stiffness that is not a positive finite number.

    Examples
    --------
    >>> from igljoin.stiffness import stiffness_from_regions
    >>> stiffness_from_regions(5, [([0, 1], 10.0), ([1, 2], 0.5)])
    array([10. ,  0.5,  0.5,  1. ,  1. ])
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise OptionsError(f"stiffness_from_regions: n={n!r} must be a positive vertex count")
    n = int(n)
    k = np.full(n, _positive(default, "stiffness_from_regions: default"))
    if isinstance(regions, (str, bytes)) or not isinstance(regions, Iterable):
        raise OptionsError(
            "stiffness_regions must be a list of (vertex_indices, k) pairs, got "
            f"{type(regions).__name__}"
        )
    for i, region in enumerate(regions):
        if not isinstance(region, (tuple, list)) or len(region) != 2:
            raise OptionsError(
                f"stiffness_regions[{i}] must be a pair (vertex_indices, k), got {region!r}"
            )
        idx, value = region
        value = _positive(value, f"stiffness_regions[{i}] k")
        try:
            idx = np.asarray(idx)
        except (TypeError, ValueError):
            idx = np.asarray([], dtype=object)
        if idx.dtype == bool:
            if idx.shape != (n,):
                raise OptionsError(
                    f"stiffness_regions[{i}]: a boolean mask needs one value per guest vertex "
                    f"({n}), got shape {idx.shape}"
                )
            idx = np.flatnonzero(idx)
        if idx.size == 0:
            continue
        if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
            raise OptionsError(
                f"stiffness_regions[{i}]: vertices must be a 1-D array of vertex indices or a "
                f"boolean mask of shape ({n},)"
            )
        idx = idx.astype(np.int64)
        if idx.min() < 0 or idx.max() >= n:
            raise OptionsError(
                f"stiffness_regions[{i}]: vertex indices range over [{idx.min()}, {idx.max()}] "
                f"but the guest has {n} vertices"
            )
        k[idx] = value
    return k


def stiffness_from_attribute(mesh: Mesh, name: str) -> tuple[np.ndarray, str]:
    """A stiffness map stored on the guest as a vertex or face attribute.

    Parameters
    ----------
    mesh : Mesh
        The guest (e.g. read by :func:`igljoin.read_mesh` from a PLY file
        with a scalar vertex or face property).
    name : str
        Attribute name, looked up in ``mesh.vertex_attributes`` and
        ``mesh.face_attributes``.

    Returns
    -------
    values : ndarray, shape (n,) or (m,)
        The attribute as float64 (relative stiffness, 1 = default tissue).
    on : {"vertex", "face"}
        Where it was found.

    Raises
    ------
    OptionsError
        No attribute of that name (the message lists the available ones),
        the name is both a vertex and a face attribute, or the attribute is
        not one number per element.
    """
    va, fa = mesh.vertex_attributes, mesh.face_attributes
    if name in va and name in fa:
        raise OptionsError(
            f"stiffness={name!r} is both a vertex and a face attribute of {mesh.name}; pass the "
            f"array itself, e.g. stiffness=guest.vertex_attributes[{name!r}]"
        )
    if name not in va and name not in fa:
        listed = ", ".join(
            [f"vertex '{a}'" for a in sorted(va)] + [f"face '{a}'" for a in sorted(fa)]
        )
        raise OptionsError(
            f"stiffness={name!r}: {mesh.name} has no attribute of that name; available: "
            f"{listed or 'none'} — give one of these, or a per-vertex or per-face array"
        )
    on = "vertex" if name in va else "face"
    values = np.asarray((va if on == "vertex" else fa)[name])
    if values.ndim != 1 or not np.issubdtype(values.dtype, np.number):
        raise OptionsError(
            f"stiffness={name!r}: the {on} attribute has shape {values.shape} and dtype "
            f"{values.dtype}; a stiffness map needs one number per {on}"
        )
    return values.astype(np.float64), on


def _given(options: Any, overrides: dict, name: str) -> Any:
    """The value of option ``name`` in ``overrides``, else in ``options``, else ``None``."""
    if name in overrides:
        return overrides[name]
    if isinstance(options, JoinOptions):
        return getattr(options, name)
    if isinstance(options, Mapping):
        return options.get(name)
    return None


def needs_guest(options: Any, overrides: dict, regions: Any) -> bool:
    """Whether the stiffness must be resolved against the guest (regions or a name).

    Parameters
    ----------
    options : JoinOptions, dict or None
    overrides : dict
        Keyword options of a join.
    regions : list of (vertex_indices, k) or None

    Returns
    -------
    bool
    """
    return regions is not None or isinstance(_given(options, overrides, "stiffness"), str)


def resolve_stiffness(guest: Mesh, options: Any, overrides: dict, regions: Any) -> dict:
    """``overrides`` with ``stiffness`` given as regions or as an attribute name made an array.

    Parameters
    ----------
    guest : Mesh
    options : JoinOptions, dict or None
    overrides : dict
        Keyword options; ``overrides["stiffness"]`` (or ``options``') may be a
        guest attribute name.
    regions : list of (vertex_indices, k) or None

    Returns
    -------
    dict
        ``overrides`` with ``stiffness`` (ndarray) and ``stiffness_on`` set.
    """
    given = _given(options, overrides, "stiffness")
    if regions is not None:
        if given is not None:
            raise OptionsError(
                "give either stiffness or stiffness_regions, not both; for regions on top of a "
                "map, pass stiffness=stiffness_from_regions(n, regions, default=...) yourself"
            )
        values, on = stiffness_from_regions(guest.n_vertices, regions), "vertex"
    else:
        values, on = stiffness_from_attribute(guest, given)
    on_given = _given(options, overrides, "stiffness_on")
    if on_given not in (None, "auto", on):
        raise OptionsError(
            f"stiffness_on={on_given!r} but the stiffness map is per {on}; leave stiffness_on "
            "unset (it is set from where the map was found)"
        )
    return {**overrides, "stiffness": values, "stiffness_on": on}


def refined_stiffness(
    options: JoinOptions, n: int, m: int, corr: Correspondence
) -> tuple[np.ndarray | None, str]:
    """The stiffness map of the options carried over to the guest refined by the seams.

    Parameters
    ----------
    options : JoinOptions
        ``stiffness`` (array or None) and ``stiffness_on``.
    n, m : int
        Vertex and face counts of the guest as given.
    corr : Correspondence
        The refined guest: inserted points (``inserted_from``, ``inserted_t``)
        and each face's parent (``face_parent``).

    Returns
    -------
    values : ndarray, shape (n',) or (m',), or None
        Per refined vertex (inserted points interpolate their edge's ends) or
        per refined face (its parent's); ``None`` without a map.
    on : {"vertex", "face"}
    """
    if options.stiffness is None:
        return None, "vertex"
    k = options.stiffness
    on = options.stiffness_on
    if on == "auto":
        if len(k) == n == m:
            raise OptionsError(
                "stiffness: the guest has as many vertices as faces, so a stiffness array "
                "is ambiguous; set stiffness_on='vertex' or 'face'"
            )
        on = "vertex" if len(k) == n else "face" if len(k) == m else "?"
    expected = n if on == "vertex" else m
    if on == "?" or len(k) != expected:
        raise OptionsError(
            f"stiffness has {len(k)} values; give one per guest vertex ({n}) or per guest "
            f"face ({m})"
        )
    if on == "vertex":
        a, b = corr.inserted_from[:, 0], corr.inserted_from[:, 1]
        extra = k[a] * (1.0 - corr.inserted_t) + k[b] * corr.inserted_t
        return np.concatenate([k, extra]), "vertex"
    return k[corr.face_parent], "face"
