"""Camera framing from the seam (NumPy only, no polyscope).

The views are set up in a frame of the seam: its long axis (first principal
axis of the host curve points), the direction in which the guest leaves the
host (mean of the host's cross-seam directions, when they agree, as on a
tube's rim) and the host's mean surface normal at the seam (when the normals
agree, as on a patch or a strip):

``"side"``
    Across the seam: the seam runs left to right and the guest lies above
    the host. On a sheet-like host the camera faces the surface; on a
    ring-like host it looks at the rim edge-on, perpendicular to the long axis.
``"along"``
    Along the seam's long axis, with the same up direction: the profile of
    host and guest through the seam, where a crease shows as a kink.

The distance is the smallest at which the deformed guest and the host within
a quarter of the guest's size of the seam fit the picture (perspective, with
a margin).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..frames import seam_frames
from ..metrics import point_polyline_distance

__all__ = ["VIEWS", "Camera", "frame_camera", "project", "seam_axes"]

VIEWS = ("side", "along")

#: Vertical field of view (degrees), polyscope's default.
FOV_DEG = 45.0
#: Camera tilt above the seam plane for the side view (degrees): shows the seam as a curve.
SIDE_ELEVATION_DEG = 15.0
#: Picture fraction left free around the framed points.
MARGIN = 1.12
#: Length of a mean of unit vectors above which their directions count as agreeing.
COHERENT = 0.2
#: Host context kept in frame: host vertices within this fraction of the guest's size of the seam.
HOST_CONTEXT = 0.25


@dataclass(frozen=True)
class Camera:
    """A perspective camera.

    Attributes
    ----------
    position, target, up : ndarray, shape (3,)
    fov_deg : float
        Vertical field of view.
    """

    position: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_deg: float = FOV_DEG

    def view_matrix(self) -> np.ndarray:
        """World-to-camera matrix (OpenGL ``lookAt``), shape (4, 4)."""
        f = _unit(self.target - self.position)
        r = _unit(np.cross(f, self.up))
        u = np.cross(r, f)
        M = np.eye(4)
        M[0, :3], M[1, :3], M[2, :3] = r, u, -f
        M[:3, 3] = -M[:3, :3] @ self.position
        return M


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else v


def _perp(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    return _unit(v - (v @ axis) * axis)


def _canonical_sign(v: np.ndarray) -> np.ndarray:
    """``v`` or ``-v``, whichever has a positive largest-magnitude component."""
    return v if v[np.argmax(np.abs(v))] >= 0 else -v


def seam_axes(result: Any) -> dict[str, np.ndarray]:
    """Centre and axes of the seam used to place the cameras.

    Parameters
    ----------
    result : JoinResult

    Returns
    -------
    dict
        ``centre`` (3,), ``up`` (3,) unit, pointing to the guest's side;
        ``side`` (3,) unit, from the centre towards the side camera;
        ``along`` (3,) unit, from the centre towards the along-the-seam camera.
    """
    host = result.host
    P = host.V[result.host_curve]
    c = P.mean(axis=0)
    _, _, Vt = np.linalg.svd(P - c, full_matrices=True)
    long_axis = _canonical_sign(Vt[0])
    fr = seam_frames(host.V, host.F, result.host_curve, result.closed)
    mean_normal = fr.normal.mean(axis=0)
    leaving = -fr.inward.mean(axis=0)
    guest_side = result.guest.V.mean(axis=0) - c
    if np.linalg.norm(mean_normal) >= np.linalg.norm(leaving):
        # sheet-like host (patch, strip): face the host surface
        side = _unit(mean_normal)
        across = leaving - (leaving @ side) * side
        # a closed seam's cross-seam directions cancel: put its long axis across the picture
        coherent = np.linalg.norm(across) >= COHERENT
        up = _unit(across) if coherent else _unit(np.cross(side, long_axis))
    else:
        # ring-like host (tube rim): the guest leaves along the mean cross-seam direction
        up = _unit(leaving)
        side = _unit(np.cross(up, _perp(long_axis, up)))
        side = _canonical_sign(side)
    if min(np.linalg.norm(side), np.linalg.norm(up)) < 0.5 or abs(side @ up) > 0.99:
        # no usable direction from the host (e.g. its normals and cross-seam directions both
        # cancel around a saddle-shaped loop): fall back to the seam's principal axes
        up, side = _canonical_sign(Vt[2]), _canonical_sign(Vt[1])
    if up @ guest_side < 0:
        up = -up
    along = _perp(long_axis, up)
    if abs(along @ side) > 0.99:  # degenerate seam (a point or a straight line seen end-on)
        along = _unit(np.cross(up, side))
    return {"centre": c, "up": up, "side": side, "along": along}


def frame_camera(
    result: Any,
    view: str,
    aspect: float,
    *,
    fov_deg: float = FOV_DEG,
    margin: float = MARGIN,
    include: np.ndarray | None = None,
    context: float = HOST_CONTEXT,
    tilt_deg: float | None = None,
) -> Camera:
    """Camera for one of :data:`VIEWS` that frames the deformed guest and the seam.

    Parameters
    ----------
    result : JoinResult
    view : {"side", "along"}
    aspect : float
        Picture width over height.
    fov_deg : float
        Vertical field of view.
    margin : float
        Scale of the framed extent (> 1 leaves a border).
    include : ndarray, shape (p, 3), optional
        Further points to keep in the picture, e.g. the guest where it
        started, so that one camera shows a join before and after.
    context : float
        Host vertices within this fraction of the guest's size of the seam
        are kept in the picture too (0: only the seam itself).
    tilt_deg : float, optional
        Angle (degrees) by which the view direction is turned: for ``"side"``
        towards the guest's side (default :data:`SIDE_ELEVATION_DEG`), for
        ``"along"`` towards the side camera (default 0: the exact profile; on
        a sheet-like host a tilt looks down onto the surface at a grazing angle).

    Returns
    -------
    Camera
    """
    axes = seam_axes(result)
    up = axes["up"]
    d = axes[view]
    if tilt_deg is None:
        tilt_deg = SIDE_ELEVATION_DEG if view == "side" else 0.0
    towards = up if view == "side" else axes["side"]
    if tilt_deg:
        e = np.radians(float(tilt_deg))
        d = _unit(np.cos(e) * d + np.sin(e) * towards)
    up = _perp(up, d)
    G = result.guest.V
    H = result.host.V
    P = H[result.host_curve]
    size = float(np.linalg.norm(np.ptp(G, axis=0)))
    near = point_polyline_distance(H, P, result.closed) <= context * size
    extra = np.empty((0, 3)) if include is None else np.asarray(include, dtype=np.float64)
    Q = np.concatenate([G, extra.reshape(-1, 3), H[near], P])
    r = _unit(np.cross(-d, up))
    B = np.stack([r, up, d])
    local = (Q - axes["centre"]) @ B.T
    mid = 0.5 * (local.min(axis=0) + local.max(axis=0))
    target = axes["centre"] + mid @ B
    local = local - mid
    t = np.tan(np.radians(fov_deg) / 2.0)
    dist = np.max(
        np.maximum(
            local[:, 2] + margin * np.abs(local[:, 0]) / (t * aspect),
            local[:, 2] + margin * np.abs(local[:, 1]) / t,
        )
    )
    return Camera(position=target + dist * d, target=target, up=up, fov_deg=fov_deg)


def project(
    points: np.ndarray, view_matrix: np.ndarray, fov_deg: float, width: int, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates of world points under a perspective camera.

    Parameters
    ----------
    points : ndarray, shape (p, 3)
    view_matrix : ndarray, shape (4, 4)
        World-to-camera matrix.
    fov_deg : float
        Vertical field of view.
    width, height : int
        Picture size in pixels.

    Returns
    -------
    xy : ndarray, shape (p, 2)
        Column and row (row 0 at the top).
    depth : ndarray, shape (p,)
        Distance in front of the camera (> 0 is visible).
    """
    X = np.asarray(points, dtype=np.float64) @ view_matrix[:3, :3].T + view_matrix[:3, 3]
    depth = -X[:, 2]
    f = 1.0 / np.tan(np.radians(fov_deg) / 2.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc_x = f * X[:, 0] / (depth * width / height)
        ndc_y = f * X[:, 1] / depth
    xy = np.stack([(ndc_x + 1.0) * 0.5 * width, (1.0 - ndc_y) * 0.5 * height], axis=1)
    return xy, depth
