"""The polyscope structures showing one join result.

A :class:`Scene` registers the host, the original guest, the deformed guest
with its quantities, the seam curve with the host's and the guest's
cross-seam tangents, and (on demand) the welded mesh; :meth:`Scene.update`
shows a new result of the same join in place.
"""

from __future__ import annotations

import weakref
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType
from typing import Any

import numpy as np

from ..errors import OptionsError
from . import colors
from .quantities import cross_seam_directions, guest_fields, seam_curves

__all__ = ["QUANTITIES", "Scene", "hidden_scenes"]

#: Face quantities of the deformed guest, by display name (the first is shown by default).
FACE_QUANTITIES = ("area change", "area change (paper scale)", "log2 area ratio")
#: Per-vertex quantities (shown when the result or solver provides them).
VERTEX_QUANTITIES = ("edge strain", "displacement", "energy")
QUANTITIES = FACE_QUANTITIES + VERTEX_QUANTITIES

#: Seam tube radius, in mean host seam edges.
SEAM_RADIUS = 0.12
#: Tangent arrows: at most this many along the seam (every k-th host curve vertex)...
MAX_TANGENTS = 48
#: ... with this length and radius in mean host seam edges, times sqrt(k), ...
TANGENT_LENGTH = 2.5
TANGENT_RADIUS = 0.12
#: ... but at most this fraction of the guest's size long, ...
TANGENT_MAX_FRACTION = 0.06
#: ... lifted off the surface along the host normal by this many arrow radii, so that an arrow
#: lying in the surface is not half buried in it (depth ties make pictures irreproducible).
TANGENT_LIFT = 1.5
#: The guest's arrow is longer and thinner than the host's: for a smooth join it continues
#: the host's arrow (no coincident surfaces, so no depth fighting between them).
GUEST_ARROW = (1.4, 0.55)

_LIVE: weakref.WeakSet = weakref.WeakSet()


class Scene:
    """Polyscope structures of one :class:`~igljoin.JoinResult`.

    Parameters
    ----------
    ps : module
        The initialised ``polyscope`` module.
    result : JoinResult
    prefix : str
        Prepended to every structure name (several scenes can coexist).
    solver : JoinSolver, optional
        Adds the per-vertex energy.
    limit : float
        Area ratio at full colour (see :func:`igljoin.viz.colors.area_colors`).
    rest : bool
        Show the original guest.
    tangents : bool
        Show the cross-seam tangents at the seam.
    edges : bool
        Draw the guest's triangle edges.
    """

    def __init__(
        self,
        ps: ModuleType,
        result: Any,
        *,
        prefix: str = "",
        solver: Any = None,
        limit: float = colors.AREA_RATIO_LIMIT,
        rest: bool = False,
        tangents: bool = True,
        edges: bool = True,
    ):
        self.ps = ps
        self.prefix = prefix
        self.limit = float(limit)
        self.quantity = QUANTITIES[0]
        self.result = result
        self.merged_error: str | None = None
        P = result.host.V[result.host_curve]
        seg = np.roll(P, -1, axis=0) - P if result.closed else np.diff(P, axis=0)
        self.seam_edge = float(np.linalg.norm(seg, axis=1).mean()) if len(seg) else 1.0
        self.host = ps.register_surface_mesh(
            self.name("host"),
            result.host.V,
            result.host.F,
            color=colors.HOST_COLOR,
            smooth_shade=True,
        )
        self.rest = ps.register_surface_mesh(
            self.name("guest (original)"),
            result.rest_guest.V,
            result.rest_guest.F,
            enabled=rest,
            color=colors.REST_COLOR,
            smooth_shade=True,
            transparency=0.5,
        )
        self.guest = ps.register_surface_mesh(
            self.name("guest"),
            result.guest.V,
            result.guest.F,
            smooth_shade=True,
            edge_width=0.6 if edges else 0.0,
            edge_color=(0.35, 0.35, 0.38),
        )
        nodes, edges_ = [], []
        for curve, _, closed in seam_curves(result):
            k, start = len(curve), sum(len(x) for x in nodes)
            idx = np.arange(k) + start
            edges_.append(
                np.stack([idx, np.roll(idx, -1)], 1) if closed else np.stack([idx[:-1], idx[1:]], 1)
            )
            nodes.append(result.host.V[curve])
        self.seam = ps.register_curve_network(
            self.name("seam"),
            np.concatenate(nodes),
            np.concatenate(edges_),
            color=colors.SEAM_COLOR,
        )
        self.seam.set_radius(SEAM_RADIUS * self.seam_edge, relative=False)
        self.tangents = bool(tangents)
        self._every = max(1, -(-len(P) // MAX_TANGENTS))
        size = float(np.linalg.norm(np.ptp(result.guest.V, axis=0)))
        self._arrow_scale = min(
            np.sqrt(self._every) * self.seam_edge, TANGENT_MAX_FRACTION * size / TANGENT_LENGTH
        )
        self._directions = cross_seam_directions(result)
        self.arrows = ps.register_point_cloud(
            self.name("seam tangents"),
            self._arrow_base(),
            color=colors.SEAM_COLOR,
            enabled=self.tangents,
        )
        self.arrows.set_radius(TANGENT_RADIUS * self._arrow_scale, relative=False)
        self.merged = None
        self._fields: dict[str, np.ndarray] = {}
        self._show(result, solver)
        _LIVE.add(self)

    def name(self, what: str) -> str:
        """Polyscope name of one of this scene's structures."""
        return f"{self.prefix}{what}"

    def structures(self) -> list:
        """The registered polyscope structures."""
        out = [self.host, self.rest, self.guest, self.seam, self.arrows]
        return out + ([self.merged] if self.merged is not None else [])

    @property
    def available_quantities(self) -> tuple[str, ...]:
        """Quantities that can be shown on the guest for the current result."""
        return FACE_QUANTITIES + tuple(self._fields)

    # -- content ----------------------------------------------------------------------------

    def _show(self, result: Any, solver: Any) -> None:
        self.result = result
        self._fields = guest_fields(result, solver)
        self._quantities()
        self._directions = cross_seam_directions(result)
        self._tangent_vectors()

    def _arrow_base(self) -> np.ndarray:
        P, normal, _, _ = self._directions
        k = self._every
        lift = TANGENT_LIFT * TANGENT_RADIUS * self._arrow_scale
        return P[::k] + lift * normal[::k]

    def _tangent_vectors(self) -> None:
        _, _, host_dir, guest_dir = self._directions
        k = self._every
        scale = self._arrow_scale
        for label, vec, color, (length, radius) in (
            ("host cross-seam tangent", host_dir, colors.HOST_TANGENT_COLOR, (1.0, 1.0)),
            ("guest cross-seam tangent", guest_dir, colors.GUEST_TANGENT_COLOR, GUEST_ARROW),
        ):
            _arrows(
                self.ps,
                self.arrows,
                label,
                vec[::k] * (TANGENT_LENGTH * length * scale),
                color,
                TANGENT_RADIUS * radius * scale,
            )
        self.arrows.set_enabled(self.tangents)

    def _quantities(self) -> None:
        r = np.asarray(self.result.area_ratio, dtype=np.float64)
        g, q = self.guest, self.quantity
        g.add_color_quantity(
            "area change",
            colors.area_colors(r, self.limit),
            defined_on="faces",
            enabled=q == "area change",
        )
        g.add_color_quantity(
            "area change (paper scale)",
            colors.magnitude_colors(r, self.limit),
            defined_on="faces",
            enabled=q == "area change (paper scale)",
        )
        with np.errstate(divide="ignore", invalid="ignore"):
            log_r = np.log2(r)
        bound = float(np.log2(self.limit))
        g.add_scalar_quantity(
            "log2 area ratio",
            np.nan_to_num(log_r, nan=0.0, posinf=bound, neginf=-bound),
            defined_on="faces",
            cmap="coolwarm",
            vminmax=(-bound, bound),
            enabled=q == "log2 area ratio",
        )
        for key, values in self._fields.items():
            v = np.nan_to_num(values)
            signed = key == "edge strain"
            top = float(np.abs(v).max()) or 1.0
            g.add_scalar_quantity(
                key,
                v,
                defined_on="vertices",
                cmap="coolwarm" if signed else "reds",
                vminmax=(-top, top) if signed else (0.0, top),
                enabled=q == key,
            )

    def update(self, result: Any, solver: Any = None) -> None:
        """Show a new result of the same join (same guest connectivity) in place."""
        if result.guest.F.shape != self.result.guest.F.shape:
            raise OptionsError(
                "Scene.update: the new result has a different guest mesh; build a new Scene"
            )
        self.guest.update_vertex_positions(result.guest.V)
        if self.merged is not None:
            self.merged.remove()
            self.merged = None
        self.merged_error = None
        self._show(result, solver)

    # -- display switches -------------------------------------------------------------------

    def set_quantity(self, name: str) -> None:
        """Colour the guest by one of :attr:`available_quantities`."""
        if name not in self.available_quantities:
            raise OptionsError(
                f"quantity {name!r} is not available; choose one of "
                f"{', '.join(self.available_quantities)}"
            )
        self.quantity = name
        self._quantities()

    def set_tangents(self, flag: bool) -> None:
        """Show or hide the cross-seam tangents."""
        self.tangents = bool(flag)
        self._tangent_vectors()

    def set_rest(self, flag: bool) -> None:
        """Show or hide the original guest."""
        self.rest.set_enabled(bool(flag))

    def set_merged(self, flag: bool) -> bool:
        """Show the welded mesh (``result.merged``) instead of host and guest.

        Returns
        -------
        bool
            Whether the welded mesh is shown (``False`` when the result has
            none or welding failed; :attr:`merged_error` says why).
        """
        if flag and self.merged is None:
            try:
                merged = self.result.merged
            except AttributeError:
                self.merged_error = "this result has no welded mesh (result.merged)"
                return False
            except Exception as exc:  # a weld error is shown, not raised, in a live session
                self.merged_error = f"welding failed: {exc}"
                return False
            mesh = getattr(merged, "mesh", merged)  # a Welded carries its Mesh
            if mesh is None:
                self.merged_error = "this result has no welded mesh"
                return False
            self.merged = self.ps.register_surface_mesh(
                self.name("merged"),
                mesh.V,
                mesh.F,
                color=colors.MERGED_COLOR,
                edge_width=0.6,
                smooth_shade=True,
            )
            ratio = mesh.face_attributes.get("area_ratio")
            if ratio is not None:
                self.merged.add_color_quantity(
                    "area change",
                    colors.area_colors(np.asarray(ratio, dtype=np.float64), self.limit),
                    defined_on="faces",
                    enabled=True,
                )
        if self.merged is not None:
            self.merged.set_enabled(bool(flag))
        self.host.set_enabled(not flag)
        self.guest.set_enabled(not flag)
        return bool(flag) and self.merged is not None

    def set_enabled(self, flag: bool) -> None:
        """Show or hide every structure of the scene."""
        for s in self.structures():
            s.set_enabled(bool(flag))

    def remove(self) -> None:
        """Remove the scene's structures from polyscope."""
        for s in self.structures():
            s.remove()
        _LIVE.discard(self)


def _arrows(ps: ModuleType, cloud: Any, name: str, V: np.ndarray, color: tuple, radius: float):
    """Ambient vectors on a point cloud with an absolute arrow radius.

    Polyscope's Python ``add_vector_quantity`` only takes a radius relative
    to the scene's length scale, which changes with the other structures
    shown; the bound quantity takes an absolute one.
    """
    bound = getattr(cloud, "bound_instance", None)
    try:
        import polyscope_bindings as psb
        from polyscope.core import glm3

        q = bound.add_vector_quantity(name, np.ascontiguousarray(V), psb.VectorType.ambient)
        q.set_radius(float(radius), False)
        q.set_color(glm3(color))
        q.set_enabled(True)
    except (AttributeError, ImportError, TypeError):  # another polyscope build
        cloud.add_vector_quantity(
            name,
            V,
            vectortype="ambient",
            enabled=True,
            color=color,
            radius=radius / max(ps.get_length_scale(), 1e-300),
        )


@contextmanager
def hidden_scenes() -> Iterator[None]:
    """Hide every live scene for the duration (e.g. while rendering a picture)."""
    saved = [(s, s.is_enabled()) for scene in list(_LIVE) for s in scene.structures()]
    for s, _ in saved:
        s.set_enabled(False)
    try:
        yield
    finally:
        for s, was in saved:
            s.set_enabled(was)
