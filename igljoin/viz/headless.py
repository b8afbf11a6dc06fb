"""Headless pictures of a join: ``render()`` and ``picture()``.

Each view is rendered off-screen (EGL when there is no display) into its own
panel with a camera framed from the seam (:mod:`igljoin.viz.camera`), then
the panels are composited with a title line and an area-ratio colour bar
(:mod:`igljoin.viz.overlay`). The scene, camera, window size, background and
scene extents are all fixed by the input, so the same result gives the same
image bytes.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_path
from ..errors import OptionsError
from . import colors
from ._backend import ensure_init, pillow
from .camera import Camera, frame_camera
from .overlay import MIN_SIZE, compose, figures_line, layout, warnings_line
from .scene import Scene, hidden_scenes

__all__ = ["Panel", "Picture", "picture", "render", "render_meshes"]

#: Accepted ``view`` values and the views each one renders.
VIEW_SETS = {"side": ("side",), "along": ("along",), "both": ("side", "along")}
CAPTIONS = {"side": "side view, across the seam", "along": "view along the seam"}
DEFAULT_SIZE = (1200, 800)
_PREFIX = "igljoin picture: "


@dataclass(frozen=True)
class Panel:
    """One rendered view inside a picture.

    Attributes
    ----------
    view : str
        ``"side"`` or ``"along"``.
    box : (int, int, int, int)
        ``x, y, width, height`` of the panel in the picture (origin top-left).
    camera : Camera
        The framed camera.
    view_matrix : ndarray, shape (4, 4)
        World-to-camera matrix polyscope reported for the render.
    fov_deg : float
        Vertical field of view polyscope used.
    """

    view: str
    box: tuple[int, int, int, int]
    camera: Camera
    view_matrix: np.ndarray
    fov_deg: float


@dataclass
class Picture:
    """A composited picture and how it was made.

    Attributes
    ----------
    image : PIL.Image.Image
        RGB picture.
    panels : list of Panel
    title, subtitle : str
        The title line and the figures line.
    warnings : str
        The quality warnings drawn after the title
        (:func:`igljoin.viz.overlay.warnings_line`).
    """

    image: Any
    panels: list[Panel] = field(default_factory=list)
    title: str = ""
    subtitle: str = ""
    warnings: str = ""

    def save(self, path: str | os.PathLike) -> Path:
        """Write the picture as PNG, atomically. Returns the path."""
        target = Path(path)
        with atomic_path(target) as tmp:
            self.image.save(tmp, format="PNG")
        return target


def _check(result: Any, view: str, size: Any, limit: float) -> tuple[tuple[str, ...], tuple]:
    if not all(hasattr(result, a) for a in ("guest", "host", "area_ratio", "host_curve")):
        raise OptionsError(
            f"result must be an igljoin.JoinResult (from JoinSolver.solve or join), got "
            f"{type(result).__name__}"
        )
    if view not in VIEW_SETS:
        raise OptionsError(f"view={view!r} must be one of 'side', 'along' or 'both'")
    try:
        w, h = (int(v) for v in size)
        ok = (w, h) == tuple(size)
    except (TypeError, ValueError):
        ok = False
    if not ok or w < MIN_SIZE[0] or h < MIN_SIZE[1] or w > 8192 or h > 8192:
        raise OptionsError(
            f"size={size!r} must be (width, height) in pixels, at least {MIN_SIZE} and at most "
            "(8192, 8192); the default is (1200, 800)"
        )
    if not (isinstance(limit, (int, float)) and np.isfinite(limit) and limit > 1.0):
        raise OptionsError(f"limit={limit!r} must be an area ratio > 1 (the default is 1.5)")
    return VIEW_SETS[view], (w, h)


_BACKGROUND_CACHE: dict[tuple, tuple[int, int, int]] = {}


def _rendered_background(ps: Any) -> tuple[int, int, int]:
    """The background as polyscope renders it (drawn once per process, in a tiny window)."""
    key = tuple(colors.BACKGROUND)
    if key not in _BACKGROUND_CACHE:
        ps.set_window_size(4, 4)
        buf = ps.screenshot_to_buffer(transparent_bg=False)
        _BACKGROUND_CACHE[key] = tuple(int(c) for c in buf[0, 0, :3])
    return _BACKGROUND_CACHE[key]


@contextmanager
def _offscreen(ps: Any, lo: np.ndarray, hi: np.ndarray) -> Iterator[tuple]:
    """Hide live scenes, fix background and scene extents; restore the viewer's state afterwards.

    The scene extents (which set polyscope's clip planes and home view) are
    the box ``lo``–``hi`` rather than whatever is registered, so that a
    picture depends only on its own content. Yields the background colour as
    rendered (RGB bytes).
    """
    saved_view = ps.get_view_as_json()
    saved_size = ps.get_window_size()
    saved_bg = ps.get_background_color()
    saved_fov = ps.get_vertical_fov_degrees()  # set_view_from_json leaves the fov alone
    with hidden_scenes():
        ps.set_background_color(colors.polyscope_background(colors.BACKGROUND))
        ps.set_ground_plane_mode("none")
        background = _rendered_background(ps)
        try:
            ps.set_automatically_compute_scene_extents(False)
            ps.set_bounding_box(lo, hi)
            ps.set_length_scale(float(np.linalg.norm(hi - lo)))
            yield background
        finally:
            ps.set_automatically_compute_scene_extents(True)
            ps.set_background_color(saved_bg)
            ps.set_window_size(*saved_size)
            ps.set_view_from_json(saved_view)
            ps.set_vertical_fov_degrees(saved_fov)


@contextmanager
def _stage(ps: Any, result: Any, limit: float) -> Iterator[tuple[Scene, tuple]]:
    """Show only a fresh scene of ``result``; restore the viewer's state afterwards.

    Yields the scene and the background colour as rendered (RGB bytes).
    """
    lo = np.minimum(result.guest.V.min(axis=0), result.host.V.min(axis=0))
    hi = np.maximum(result.guest.V.max(axis=0), result.host.V.max(axis=0))
    with _offscreen(ps, lo, hi) as background:
        scene = Scene(ps, result, prefix=_PREFIX, limit=limit, edges=False)
        try:
            yield scene, background
        finally:
            scene.remove()


def _shoot(ps: Any, cam: Camera, w: int, h: int) -> tuple[np.ndarray, np.ndarray, float]:
    ps.set_window_size(w, h)
    ps.set_vertical_fov_degrees(cam.fov_deg)
    # The clip planes follow the view centre, which look_at keeps from the previous view:
    # reset it to the (fixed) home view first so nothing carries over from earlier renders.
    ps.reset_camera_to_home_view()
    ps.look_at_dir(cam.position, cam.target, cam.up)
    buf = ps.screenshot_to_buffer(transparent_bg=False)
    if buf.shape[:2] != (h, w):  # a high-DPI display scales the framebuffer
        PIL = pillow()
        buf = np.asarray(PIL.Image.fromarray(buf).resize((w, h), PIL.Image.Resampling.LANCZOS))
    return (
        np.ascontiguousarray(buf[:, :, :3]),
        np.asarray(ps.get_camera_view_matrix(), dtype=np.float64),
        float(ps.get_vertical_fov_degrees()),
    )


def render_meshes(
    host: Any,
    guest: Any,
    guest_colors: np.ndarray,
    camera: Camera,
    size: tuple[int, int],
    *,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    host_color: tuple = colors.HOST_COLOR,
) -> tuple[np.ndarray, tuple[int, int, int]]:
    """Render a host and a guest with given face colours, off-screen, from a given camera.

    The bare panel behind figures that show meshes which are not a join
    result, such as the guest where it starts (the paper's "initial
    configuration"), next to panels of joins seen through the same camera.

    Parameters
    ----------
    host, guest : Mesh
        Anything with ``V`` (n, 3) and ``F`` (m, 3).
    guest_colors : ndarray, shape (m, 3)
        RGB in [0, 1] per guest face (e.g. :func:`igljoin.viz.colors.area_colors`).
    camera : Camera
        E.g. from :func:`igljoin.viz.frame_camera`.
    size : (int, int)
        Width and height in pixels.
    bounds : (ndarray, ndarray), optional
        Scene box ``(lo, hi)``, shape (3,) each; it sets polyscope's clip
        planes, so give panels that are compared the same box (default: the
        box of host and guest).
    host_color : tuple of float
        RGB of the host.

    Returns
    -------
    image : ndarray of uint8, shape (h, w, 3)
    background : (int, int, int)
        The background colour as rendered.
    """
    w, h = (int(v) for v in size)
    guest_colors = np.asarray(guest_colors, dtype=np.float64)
    if guest_colors.shape != (len(guest.F), 3):
        raise OptionsError(
            f"guest_colors must have shape ({len(guest.F)}, 3), one RGB per guest face; "
            f"got {guest_colors.shape}"
        )
    if bounds is None:
        lo = np.minimum(guest.V.min(axis=0), host.V.min(axis=0))
        hi = np.maximum(guest.V.max(axis=0), host.V.max(axis=0))
    else:
        lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    ps = ensure_init(headless=True)
    with _offscreen(ps, lo, hi) as background:
        structures = [
            ps.register_surface_mesh(
                f"{_PREFIX}panel host", host.V, host.F, color=host_color, smooth_shade=True
            ),
            ps.register_surface_mesh(
                f"{_PREFIX}panel guest", guest.V, guest.F, smooth_shade=True, edge_width=0.0
            ),
        ]
        try:
            structures[1].add_color_quantity(
                "colour", guest_colors, defined_on="faces", enabled=True
            )
            rgb, _, _ = _shoot(ps, camera, w, h)
        finally:
            for s in structures:
                s.remove()
    return rgb, background


def default_title(result: Any) -> str:
    """Title used when none is given: the result's name, or the mesh names."""
    name = getattr(result, "name", None)
    return str(name) if name else f"{result.guest.name} joined to {result.host.name}"


def picture(
    result: Any,
    *,
    view: str = "side",
    size: tuple[int, int] = DEFAULT_SIZE,
    title: str | None = None,
    limit: float = colors.AREA_RATIO_LIMIT,
) -> Picture:
    """Render a join off-screen and composite its title, quality warnings and colour bar.

    The title line ends with the result's quality warnings (their codes, in
    orange) or "no quality warnings" (see ``docs/warnings.md``).

    Parameters
    ----------
    result : JoinResult
    view : {"side", "along", "both"}
        Across the seam, along it, or both side by side.
    size : (int, int)
        Picture width and height in pixels.
    title : str, optional
        Case name for the title line (default: the mesh names).
    limit : float
        Area ratio drawn at full red (``1 / limit`` at full blue).

    Returns
    -------
    Picture
        The image and, per panel, the camera used (to relate pixels to the mesh).
    """
    views, (w, h) = _check(result, view, size, limit)
    pillow()  # fail early, before polyscope starts, if Pillow is missing
    ps = ensure_init(headless=True)
    lay = layout((w, h), len(views))
    shots, panels = [], []
    with _stage(ps, result, float(limit)) as (_, background):
        for name, box in zip(views, lay.panels):
            cam = frame_camera(result, name, box[2] / box[3])
            rgb, M, fov = _shoot(ps, cam, box[2], box[3])
            shots.append(rgb)
            panels.append(Panel(name, box, cam, M, fov))
    ratio = result.metrics.get("area_ratio", {})
    text = title if title is not None else default_title(result)
    sub = figures_line(result)
    notice = warnings_line(result)
    image = compose(
        shots,
        lay,
        title=text,
        subtitle=sub,
        captions=[CAPTIONS[v] for v in views],
        limit=float(limit),
        data_range=(ratio.get("min"), ratio.get("max")),
        background=background,
        notice=notice,
        alert=bool(getattr(result, "warnings", ())),
    )
    return Picture(image=image, panels=panels, title=text, subtitle=sub, warnings=notice)


def render(
    result: Any,
    path: str | os.PathLike,
    *,
    view: str = "side",
    size: tuple[int, int] = DEFAULT_SIZE,
    title: str | None = None,
    limit: float = colors.AREA_RATIO_LIMIT,
) -> Path:
    """Render a join to a PNG file, headless: :func:`picture`, saved.

    Parameters
    ----------
    result : JoinResult
    path : str or os.PathLike
        Output ``.png``; its directory must exist. Written atomically.
    view, size, title, limit
        As in :func:`picture`.

    Returns
    -------
    pathlib.Path
        ``path``.

    Examples
    --------
    >>> import igljoin, igljoin.viz
    >>> s = igljoin.phantoms.paper_sample("end_to_end", "shorter", resolution=0.5)
    >>> res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
    >>> igljoin.viz.render(res, "join.png", view="both", title=s.name)  # doctest: +SKIP
    PosixPath('join.png')
    """
    target = Path(path)
    if target.suffix.lower() != ".png":
        raise OptionsError(f"path={str(path)!r} must end in .png (pictures are written as PNG)")
    if not target.parent.is_dir():  # fail before rendering, not after
        raise FileNotFoundError(
            errno.ENOENT,
            f"cannot write {target}: its directory {target.parent} does not exist; "
            "create the directory first",
            str(target.parent),
        )
    return picture(result, view=view, size=size, title=title, limit=limit).save(target)
