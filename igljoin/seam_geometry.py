"""One seam's geometry: a host, one of its boundary curves, and a guest lying on it.

The crease measures (:mod:`igljoin.crease`, :func:`igljoin.metrics.crease_angles`)
read the same seven arrays; a :class:`SeamGeometry` carries them together,
with their dtypes settled once.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

__all__ = ["SeamGeometry"]


@dataclass(frozen=True)
class SeamGeometry:
    """A host curve and the guest vertices on it.

    Parameters
    ----------
    Vh, Fh : array_like, shapes (n_h, 3) and (m_h, 3)
        The host's vertex positions and triangles (vertex indices).
    host_curve : array_like of int, shape (k,)
        Ordered host curve vertices.
    Vg, Fg : array_like, shapes (n_g, 3) and (m_g, 3)
        The guest's, joined, at rest, or in place for an uncut reference.
    guest_at_host : array_like of int, shape (k,)
        Guest vertex on each host curve vertex.
    closed : bool
        Whether the curve is a closed loop.

    Notes
    -----
    The arrays are kept as given where they already have the dtype
    (float64 positions, int64 indices), so a record costs no copy.
    """

    Vh: np.ndarray
    Fh: np.ndarray
    host_curve: np.ndarray
    Vg: np.ndarray
    Fg: np.ndarray
    guest_at_host: np.ndarray
    closed: bool

    def __post_init__(self) -> None:
        for name in ("Vh", "Vg"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=np.float64))
        for name in ("Fh", "host_curve", "Fg", "guest_at_host"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=np.int64))
        object.__setattr__(self, "closed", bool(self.closed))

    @property
    def host_points(self) -> np.ndarray:
        """The host curve's positions, shape (k, 3)."""
        return self.Vh[self.host_curve]

    def with_guest(self, Vg: np.ndarray) -> SeamGeometry:
        """The same seam with the guest at other positions (same faces), e.g. at rest."""
        return dataclasses.replace(self, Vg=Vg)
