"""Inspection of joins with polyscope: an interactive session and headless pictures.

Optional: needs the ``viz`` extra (``pip install 'igljoin[viz]'``: polyscope
and Pillow). Importing this package does not import polyscope; the first
call that draws does, and initialises polyscope once per process (off-screen
EGL when there is no display).

* :func:`render` / :func:`picture` — the join rendered off-screen with a
  title line and an area-ratio colour bar, framed from the seam;
  :func:`render_meshes` renders a bare panel of any host and guest with
  given face colours from a given camera.
* :func:`igljoin.viz.figures.paper_figures` — the paper's Figs. 2 and 3
  from the demo's joins (what ``make demo`` draws).
* :func:`inspect` / :class:`Session` — an interactive viewer with a panel to
  switch the smooth-join term, move the weights and the iteration count and
  re-solve live.

Area change is drawn on the paper's scale (white: no change, dark red:
large change), split into blue for shrink and red for stretch, symmetric in
``log2(area ratio)`` (:mod:`igljoin.viz.colors`).
"""

from __future__ import annotations

from .camera import Camera, frame_camera, project
from .colors import AREA_RATIO_LIMIT, area_colors, magnitude_colors
from .headless import Panel, Picture, picture, render, render_meshes
from .scene import QUANTITIES
from .session import Session, inspect

__all__ = [
    "AREA_RATIO_LIMIT",
    "QUANTITIES",
    "Camera",
    "Panel",
    "Picture",
    "Session",
    "area_colors",
    "frame_camera",
    "inspect",
    "magnitude_colors",
    "picture",
    "project",
    "render",
    "render_meshes",
]
