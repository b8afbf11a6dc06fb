"""Marks drawn over a rendered picture: the outline and names of regions of the guest.

A picture's panels keep the camera each view was rendered with
(:class:`igljoin.viz.Panel`), so points of the mesh can be projected onto
the picture and marked there with Pillow. The marks are drawn over the
rendered surface without a depth test: use them on views that see the
region face-on (a patch's ``"side"`` view), not edge-on.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import OptionsError
from ._backend import pillow
from .camera import project
from .overlay import fonts

__all__ = ["region_boundary", "mark_regions"]

#: Outline colour of a marked region: near black, unlike the seam (yellow) and the area scale.
OUTLINE = (16, 16, 18)
#: Label text and its backing box.
LABEL_TEXT = (16, 16, 18)
LABEL_BOX = (236, 236, 236)


def region_boundary(F: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Edges between a face inside a region and a face outside it.

    Parameters
    ----------
    F : ndarray of int, shape (m, 3)
    inside : ndarray of bool, shape (m,)

    Returns
    -------
    ndarray of int64, shape (b, 2)
        Vertex pairs (smaller index first), sorted.
    """
    F = np.asarray(F, dtype=np.int64)
    inside = np.asarray(inside, dtype=bool)
    if inside.shape != (len(F),):
        raise OptionsError(
            f"inside must have shape ({len(F)},), one flag per face; got {inside.shape}"
        )
    edges = np.sort(F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    side = np.repeat(inside, 3)
    key, first, inverse = np.unique(edges, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    n_in = np.bincount(inverse, weights=side, minlength=len(key))
    n_all = np.bincount(inverse, minlength=len(key))
    return key[(n_in > 0) & (n_in < n_all)]


def _centroid(V: np.ndarray, F: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted centroid of some faces, shape (3,)."""
    T = V[F[faces]]
    area = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)
    centres = T.mean(axis=1)
    return (area[:, None] * centres).sum(axis=0) / max(float(area.sum()), 1e-300)


def mark_regions(
    picture: Any,
    mesh: Any,
    inside: np.ndarray,
    labels: tuple[str, str],
    *,
    views: Sequence[str] = ("side",),
) -> Any:
    """Outline a region of the guest and name it and the rest, on a picture (in place).

    Parameters
    ----------
    picture : igljoin.viz.Picture
        From :func:`igljoin.viz.picture`; its image is drawn on.
    mesh : Mesh
        The mesh shown in the picture whose faces ``inside`` refers to (the
        deformed guest, ``result.guest``).
    inside : ndarray of bool, shape (m,)
        Faces of the region.
    labels : (str, str)
        Names written on the region and on the rest of the mesh.
    views : sequence of str
        Panels to mark (views that see the region face-on).

    Returns
    -------
    igljoin.viz.Picture
        ``picture``.
    """
    inside = np.asarray(inside, dtype=bool)
    V, F = np.asarray(mesh.V, dtype=np.float64), np.asarray(mesh.F, dtype=np.int64)
    if not inside.any() or inside.all():
        raise OptionsError("inside must select some faces of the mesh but not all of them")
    PIL = pillow()
    draw = PIL.ImageDraw.Draw(picture.image)
    edges = region_boundary(F, inside)
    for panel in picture.panels:
        if panel.view not in views:
            continue
        x0, y0, w, h = panel.box
        fs = max(11, round(h / 26))
        _, small = fonts(fs)

        def to_picture(P: np.ndarray, panel=panel, x0=x0, y0=y0, w=w, h=h) -> np.ndarray:
            xy, _ = project(P, panel.view_matrix, panel.fov_deg, w, h)
            return xy + np.array([x0, y0])

        ends = to_picture(V[edges.reshape(-1)]).reshape(-1, 2, 2)
        for a, b in ends:
            draw.line([tuple(a), tuple(b)], fill=OUTLINE, width=max(2, fs // 6))
        for text, faces in (
            (labels[0], np.flatnonzero(inside)),
            (labels[1], np.flatnonzero(~inside)),
        ):
            cx, cy = to_picture(_centroid(V, F, faces)[None])[0]
            left, top, right, bottom = draw.textbbox((cx, cy), text, font=small, anchor="mm")
            draw.rectangle([left - 4, top - 3, right + 4, bottom + 3], fill=LABEL_BOX)
            draw.text((cx, cy), text, fill=LABEL_TEXT, font=small, anchor="mm")
    return picture
