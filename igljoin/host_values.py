"""The rigid host's values along its seam curves, made once and kept by a solver.

The host does not move, so its band fits, one-ring inward directions,
dihedral angles and distances along a curve are the same on every solve. A
:class:`HostValues` makes each the first time it is asked for and keeps it;
the solver owns one and passes it to the functions that build its terms and
measure its results. The functions it calls stay plain functions of arrays.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from .bandfit import BandFit, band_fit
from .boundary import SelectedCurve
from .frames import seam_frames
from .mesh import Mesh
from .metrics import PolylineDistance, host_dihedral_angles

__all__ = ["HostValues"]


class HostValues:
    """Values of a rigid host along its curves, made on first use and kept.

    Parameters
    ----------
    host : Mesh
        The (combined) host; the smooth join's band fits are made on it.
    measured : Mesh, optional
        The host the one-ring measures read: the host itself (default) or
        its neighbourhood near the curves, with the same vertex indices
        (:func:`igljoin.seams.host_neighbourhood`).

    Attributes
    ----------
    made : dict
        The values made so far, keyed by ``(kind, ...)`` with ``kind`` one of
        ``"band_fit"``, ``"inward"``, ``"dihedral"``, ``"distance"``.
    """

    def __init__(self, host: Mesh, measured: Mesh | None = None):
        self.host = host
        self.measured = host if measured is None else measured
        self.made: dict[tuple, Any] = {}

    def _kept(self, key: tuple, make: Callable[[], Any]) -> Any:
        if key not in self.made:
            self.made[key] = make()
        return self.made[key]

    def band_fit(self, curve: SelectedCurve, band: float) -> BandFit:
        """The host's band fit along ``curve`` (:func:`igljoin.bandfit.band_fit`)."""
        key = ("band_fit", curve.indices.tobytes(), bool(curve.closed), float(band))
        V, F = self.host.V, self.host.F
        return self._kept(key, lambda: band_fit(V, F, curve.indices, curve.closed, band))

    def inward(self, curve: SelectedCurve) -> np.ndarray:
        """The host's one-ring inward directions along ``curve``, shape (k, 3)."""
        key = ("inward", curve.indices.tobytes(), bool(curve.closed))
        V, F = self.measured.V, self.measured.F
        return self._kept(key, lambda: seam_frames(V, F, curve.indices, curve.closed).inward)

    def dihedral(self, curve: np.ndarray) -> np.ndarray:
        """The host's dihedral angles (degrees) near ``curve``, shape (p,).

        ``curve`` is an index array, shape (k,) (one curve, or several
        concatenated); see :func:`igljoin.metrics.host_dihedral_angles`.
        """
        key = ("dihedral", np.asarray(curve).tobytes())
        V, F = self.measured.V, self.measured.F
        return self._kept(key, lambda: host_dihedral_angles(V, F, curve))

    def distance(self, curve: SelectedCurve) -> PolylineDistance:
        """Distances to the host curve ``curve`` (:class:`igljoin.metrics.PolylineDistance`)."""
        key = ("distance", curve.indices.tobytes(), bool(curve.closed))
        V = self.measured.V
        return self._kept(key, lambda: PolylineDistance(V[curve.indices], curve.closed))
