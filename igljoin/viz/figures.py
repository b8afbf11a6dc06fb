"""The paper's Figs. 2 and 3 redrawn from the demo's joins (what ``make demo`` draws).

One figure per scenario, laid out like the paper's: rows

1. the initial configuration (host and the guest where the sample places it,
   undeformed, so white),
2. the join without the smooth-join term,
3. the join with it, seen across the seam,
4. the join with it, seen along the seam's long axis from just above the host
   (:data:`ALONG_TILT_DEG`): the profile through the seam, where a crease is a kink,

and columns (a) shorter, (b) equal, (c) longer guest boundary. Rows 1–3 of a
column share one camera, framed on the initial and both joined guests, so a
row compares like with like. Every guest is coloured by area change on one
scale for the whole figure (blue shrink, white unchanged, red stretch,
:func:`igljoin.viz.colors.area_colors`) with one colour bar; the host is drawn
in :data:`igljoin.viz.colors.HOST_COLOR`, which is off that scale.

Everything — cameras, scene extents, scale, text — follows from the input, so
the same runs give the same PNG bytes.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_path
from ..errors import OptionsError
from ..frames import seam_frames
from . import colors
from ._backend import ensure_init, pillow
from .camera import Camera, frame_camera, project, seam_axes
from .headless import render_meshes
from .overlay import _DIM, _TEXT, colour_bar, fonts

__all__ = [
    "FIGURES",
    "FigureLayout",
    "end_to_side_figure",
    "figure_layout",
    "paper_figure",
    "paper_figures",
    "scale",
]

#: Output key, scenario and title of each figure.
FIGURES = {
    "figure_end_to_end": ("end_to_end", "End-to-end join, laid out like the paper's Fig. 2"),
    "figure_partial_patch": ("partial_patch", "Partial patching, laid out like the paper's Fig. 3"),
}
#: Column order and the paper's column letters.
LENGTHS = ("shorter", "equal", "longer")
COLUMN_LETTERS = {"shorter": "a", "equal": "b", "longer": "c"}
ROW_LABELS = (
    "(1) initial configuration",
    "(2) without smooth join",
    "(3) with smooth join, across the seam",
    "(4) with smooth join, along the seam",
)
#: Rendered panel size (width, height) in pixels: 3 x 4 panels and the bands make ~1530 x 1830.
PANEL_SIZE = (440, 400)
#: Candidate area ratios at full colour; the figure uses the smallest that holds
#: :data:`SCALE_PERCENTILE` per cent of its deformed faces (the rest saturate; the colour bar
#: marks the true extremes).
NICE_LIMITS = (1.1, 1.25, 1.5, 2.0, 3.0, 4.0, 8.0)
SCALE_PERCENTILE = 99.0
#: Host context of the along-the-seam view (fraction of the guest's size around the seam): less
#: than the side view's, so the profile through the seam fills the panel.
ALONG_CONTEXT = 0.1
#: Tilt of the along-the-seam view towards the side camera (degrees): a grazing view that
#: shows the guest's colours and the profile through the seam at once.
ALONG_TILT_DEG = 25.0
#: Scenarios whose rows 2 and 3 get a seam close-up inset. Seen face-on, a patch looks the same
#: with and without the smooth-join term (the guests differ by under 6 % of their size, mostly
#: in a band along the seam); the close-up shows the seam where the crease without the term is
#: sharpest, along the seam's tangent there, so the kink or its absence is in profile.
SEAM_INSET_SCENARIOS = ("partial_patch",)
#: The close-up: half the width it frames at the seam (fraction of the guest's size), its
#: elevation above the host's tangent plane (degrees) and its size (fraction of the panel).
INSET_HALF_WIDTH = 0.1
INSET_ELEVATION_DEG = 8.0
INSET_FRACTION = 0.45
INSET_FOV_DEG = 30.0
#: Backing of the inset's label (the figure's background, darker).
_INSET_LABEL = (28, 29, 33)


@dataclass(frozen=True)
class FigureLayout:
    """Where things go on a figure's canvas (pixels, origin top-left).

    Attributes
    ----------
    size, font_size
        As in :class:`igljoin.viz.overlay.Layout`.
    title_height : int
        Title band (title and one explanatory line).
    header_height : int
        Band of column headers under the title.
    caption_height : int
        Strip above each panel with its key figures.
    label_width : int
        Column of (rotated) row labels on the left.
    panel_size : (int, int)
        Width and height of each 3D panel.
    rows, columns : int
    bar : (int, int, int, int)
        ``x, y, width, height`` of the colour bar column on the right.
    """

    size: tuple[int, int]
    font_size: int
    title_height: int
    header_height: int
    caption_height: int
    label_width: int
    panel_size: tuple[int, int]
    rows: int
    columns: int
    bar: tuple[int, int, int, int]

    def panel(self, row: int, column: int) -> tuple[int, int, int, int]:
        """``x, y, width, height`` of the 3D panel in ``row`` and ``column`` (both from 0).

        Its caption strip is the :attr:`caption_height` pixels right above it.
        """
        if not (0 <= row < self.rows and 0 <= column < self.columns):
            raise OptionsError(
                f"panel ({row}, {column}) is outside the {self.rows} x {self.columns} grid"
            )
        w, h = self.panel_size
        return (
            self.label_width + column * w,
            self.title_height
            + self.header_height
            + row * (h + self.caption_height)
            + self.caption_height,
            w,
            h,
        )


def figure_layout(
    columns: int = len(LENGTHS),
    rows: int = len(ROW_LABELS),
    panel_size: tuple[int, int] = PANEL_SIZE,
) -> FigureLayout:
    """The grid of a paper figure: title band, column headers, row labels, panels, colour bar.

    Parameters
    ----------
    columns, rows : int
        Grid size (the paper's figures are 3 columns by 4 rows).
    panel_size : (int, int)
        Width and height of one panel in pixels.

    Returns
    -------
    FigureLayout

    Examples
    --------
    >>> lay = figure_layout()
    >>> lay.size, lay.panel(0, 0)
    ((1530, 1826), (50, 148, 440, 400))
    """
    pw, ph = (int(v) for v in panel_size)
    fs = 20
    title_h = 3 * fs + fs // 2 + 12
    header_h = 2 * fs
    caption_h = 4 * fs // 3
    label_w = 5 * fs // 2
    bar_w = 8 * fs
    width = label_w + columns * pw + bar_w
    grid_h = rows * (ph + caption_h)
    bar = (label_w + columns * pw, title_h + header_h, bar_w, grid_h)
    return FigureLayout(
        size=(width, title_h + header_h + grid_h),
        font_size=fs,
        title_height=title_h,
        header_height=header_h,
        caption_height=caption_h,
        label_width=label_w,
        panel_size=(pw, ph),
        rows=rows,
        columns=columns,
        bar=bar,
    )


def scale(ratios: Sequence[np.ndarray]) -> float:
    """The figure's area ratio at full colour: one of :data:`NICE_LIMITS`.

    The smallest candidate at or above the :data:`SCALE_PERCENTILE` percentile
    of ``max(r, 1 / r)`` over all faces, so that a figure whose guests hardly
    change still shows colour and one whose guests change a lot does not
    saturate.

    Parameters
    ----------
    ratios : sequence of ndarray
        Area ratios (deformed over rest) of every deformed guest in the figure.

    Returns
    -------
    float

    Examples
    --------
    >>> scale([np.array([1.0, 1.3, 0.9])])
    1.5
    """
    r = np.concatenate([np.asarray(a, dtype=np.float64).reshape(-1) for a in ratios])
    r = r[np.isfinite(r) & (r > 0)]
    if r.size == 0:
        return colors.AREA_RATIO_LIMIT
    change = float(np.percentile(np.exp2(np.abs(np.log2(r))), SCALE_PERCENTILE))
    return next((v for v in NICE_LIMITS if v >= change), NICE_LIMITS[-1])


def _white(mesh: Any) -> np.ndarray:
    return np.ones((len(mesh.F), 3))


def _bounds(*meshes: Any) -> tuple[np.ndarray, np.ndarray]:
    V = np.concatenate([m.V for m in meshes])
    return V.min(axis=0), V.max(axis=0)


def _column_panels(run: Any, aspect: float, limit: float) -> list[tuple]:
    """``(host, guest, face colours, camera)`` of the four rows of one sample's column."""
    s, plain, smooth = run.sample, run.plain, run.smooth
    side = frame_camera(smooth, "side", aspect, include=np.concatenate([s.guest.V, plain.guest.V]))
    along = frame_camera(smooth, "along", aspect, context=ALONG_CONTEXT, tilt_deg=ALONG_TILT_DEG)
    return [
        (s.host, s.guest, _white(s.guest), side),
        (plain.host, plain.guest, colors.area_colors(plain.area_ratio, limit), side),
        (smooth.host, smooth.guest, colors.area_colors(smooth.area_ratio, limit), side),
        (smooth.host, smooth.guest, colors.area_colors(smooth.area_ratio, limit), along),
    ]


def seam_closeup(run: Any) -> tuple[Camera, int]:
    """Camera of the seam close-up: along the seam where its crease without the term is sharpest.

    Parameters
    ----------
    run : igljoin.demo.SampleRun

    Returns
    -------
    camera : Camera
        Looking along the host curve's tangent at that seam vertex, from
        :data:`INSET_ELEVATION_DEG` above the host's tangent plane on the
        side cameras' side, framing :data:`INSET_HALF_WIDTH` of the guest's
        size on either side of the seam.
    k : int
        The seam vertex (index into ``run.smooth.host_curve``).
    """
    res = run.smooth
    k = int(np.argmax(np.nan_to_num(np.asarray(run.plain.crease, dtype=np.float64), nan=-1.0)))
    frames = seam_frames(res.host.V, res.host.F, res.host_curve, res.closed)
    p = res.host.V[res.host_curve[k]]
    normal = frames.normal[k]
    if normal @ seam_axes(res)["side"] < 0:  # look from the side the overview is seen from
        normal = -normal
    e = np.radians(INSET_ELEVATION_DEG)
    d = np.cos(e) * frames.tangent[k] + np.sin(e) * normal
    size = float(np.linalg.norm(np.ptp(res.guest.V, axis=0)))
    dist = INSET_HALF_WIDTH * size / np.tan(np.radians(INSET_FOV_DEG) / 2.0)
    return Camera(position=p + dist * d, target=p, up=normal, fov_deg=INSET_FOV_DEG), k


def _captions(run: Any) -> list[str]:
    # ASCII and the degree sign only: Pillow's built-in font has no en dash and no times sign
    def joined(res: Any) -> str:
        r = res.area_ratio
        codes = [w.code for w in getattr(res, "warnings", ())]
        return (
            f"mean crease {res.crease.mean():.2f}\u00b0, area ratio "
            f"{np.nanmin(r):.2f} to {np.nanmax(r):.2f}"
            + (f"; warnings: {', '.join(codes)}" if codes else "")
        )

    return [
        "where the sample places the guest, undeformed",
        joined(run.plain),
        joined(run.smooth),
        f"mean crease {run.smooth.crease.mean():.2f}\u00b0, seen along the seam",
    ]


def _draw_inset(
    img: Any,
    draw: Any,
    panel: tuple,
    rgb: np.ndarray,
    point: np.ndarray,
    cam: Camera,
    crease: float,
    font: Any,
) -> None:
    """Paste a seam close-up into the panel corner farthest from its spot; ring the spot."""
    PIL = pillow()
    x, y, w, h = panel
    ih, iw = rgb.shape[:2]
    xy, depth = project(point[None], cam.view_matrix(), cam.fov_deg, w, h)
    px, py = xy[0]
    seen = bool(depth[0] > 0 and 0 <= px < w and 0 <= py < h)
    corners = [(w - iw - 4, h - ih - 4), (4, h - ih - 4), (w - iw - 4, 4), (4, 4)]
    if seen:  # the corner whose inset centre lies farthest from the spot
        corners.sort(key=lambda c: -((c[0] + iw / 2 - px) ** 2 + (c[1] + ih / 2 - py) ** 2))
    ix, iy = x + corners[0][0], y + corners[0][1]
    img.paste(PIL.Image.fromarray(rgb), (ix, iy))
    draw.rectangle([ix - 1, iy - 1, ix + iw, iy + ih], outline=_TEXT)
    step = round(1.15 * getattr(font, "size", 11))
    lines = ["seam close-up at (o)", f"crease there {crease:.1f}\u00b0"]
    width = max(draw.textlength(t, font=font) for t in lines)
    draw.rectangle([ix, iy, ix + width + 8, iy + 6 + step * len(lines)], fill=_INSET_LABEL)
    for j, text in enumerate(lines):
        draw.text((ix + 4, iy + 3 + j * step), text, fill=_TEXT, font=font)
    if seen:
        r = 6
        draw.ellipse([x + px - r, y + py - r, x + px + r, y + py + r], outline=_TEXT, width=2)


def _vertical_text(img: Any, text: str, box: tuple, font: Any, background: tuple) -> None:
    """Write ``text`` rotated a quarter turn (reading upwards), centred in ``box``."""
    PIL = pillow()
    x, y, w, h = box
    left, top, right, bottom = font.getbbox(text)
    strip = PIL.Image.new("RGB", (right - left + 4, bottom - top + 4), background)
    PIL.ImageDraw.Draw(strip).text((2 - left, 2 - top), text, fill=_TEXT, font=font)
    strip = strip.transpose(PIL.Image.Transpose.ROTATE_90)
    img.paste(strip, (x + (w - strip.width) // 2, y + (h - strip.height) // 2))


def _canvas(
    size: tuple[int, int],
    background: tuple,
    shots: list[tuple[tuple[int, int], np.ndarray]],
    title: str,
    explanation: str,
    font_size: int,
) -> tuple[Any, Any]:
    """A figure's canvas with its rendered panels pasted and its title band written.

    Parameters
    ----------
    size : (int, int)
        Canvas width and height in pixels.
    background : (int, int, int)
        Canvas colour (the renderer's background).
    shots : list of ((int, int), ndarray of uint8, shape (h, w, 3))
        Top-left corner of each panel and its rendered pixels.
    title : str
        Title line, in the large font.
    explanation : str
        The line under the title, in the small font.
    font_size : int
        Size of the large font (:func:`igljoin.viz.overlay.fonts`).

    Returns
    -------
    img : PIL.Image.Image
    draw : PIL.ImageDraw.ImageDraw
        Drawing on ``img``, for the rest of the figure.
    """
    PIL = pillow()
    img = PIL.Image.new("RGB", size, background)
    for xy, rgb in shots:
        img.paste(PIL.Image.fromarray(rgb), xy)
    draw = PIL.ImageDraw.Draw(img)
    font, small = fonts(font_size)
    fs = font_size
    draw.text((fs // 2, fs // 3), title, fill=_TEXT, font=font)
    draw.text((fs // 2, fs // 3 + round(1.4 * fs)), explanation, fill=_DIM, font=small)
    return img, draw


def paper_figure(runs: Sequence[Any], title: str = "") -> Any:
    """Draw one paper figure from the runs of one scenario.

    Parameters
    ----------
    runs : sequence of igljoin.demo.SampleRun
        One per column, left to right (the paper: shorter, equal, longer),
        all of the same scenario.
    title : str
        Title line.

    Returns
    -------
    PIL.Image.Image
        RGB figure of size :func:`figure_layout` ``(len(runs)).size``.
    """
    if not runs:
        raise OptionsError("paper_figure needs at least one SampleRun (one per column)")
    pillow()  # fail early, before polyscope starts, if Pillow is missing
    ensure_init(headless=True)
    lay = figure_layout(columns=len(runs))
    pw, ph = lay.panel_size
    deformed = [res.area_ratio for r in runs for res in (r.plain, r.smooth)]
    limit = scale(deformed)
    data = np.concatenate(deformed)
    shots, background = [], None
    insets = []  # (row, column, close-up RGB, seam point, overview camera, crease there)
    iw, ih = round(INSET_FRACTION * pw), round(INSET_FRACTION * ph)
    for col, run in enumerate(runs):
        box = _bounds(run.sample.host, run.sample.guest, run.plain.guest, run.smooth.guest)
        panels = _column_panels(run, pw / ph, limit)
        for row, (host, guest, face_colors, cam) in enumerate(panels):
            rgb, background = render_meshes(host, guest, face_colors, cam, (pw, ph), bounds=box)
            shots.append((lay.panel(row, col)[:2], rgb))
        if run.sample.scenario in SEAM_INSET_SCENARIOS:
            close, k = seam_closeup(run)
            point = run.smooth.host.V[run.smooth.host_curve[k]]
            for row, res in ((1, run.plain), (2, run.smooth)):
                host, guest, face_colors, cam = panels[row]
                rgb, _ = render_meshes(host, guest, face_colors, close, (iw, ih), bounds=box)
                insets.append((row, col, rgb, point, cam, float(res.crease[k])))
    fs = lay.font_size
    font, small = fonts(fs)
    img, draw = _canvas(
        lay.size,
        background,
        shots,
        title,
        "Guest coloured by area ratio (deformed / rest) on one scale for the whole figure: "
        "blue shrink, white no change, red stretch. Host (rigid) in grey-green.",
        fs,
    )
    for row, col, rgb, point, cam, crease in insets:
        _draw_inset(img, draw, lay.panel(row, col), rgb, point, cam, crease, small)
    draw.text(
        (fs // 2, fs // 3 + round(2.5 * fs)),
        f"Rows 1 to 3 of a column share one camera; row 4 looks along the seam's long axis, "
        f"turned {ALONG_TILT_DEG:g}\u00b0 towards row 3's camera. "
        "Crease: angle between host and guest across the seam.",
        fill=_DIM,
        font=small,
    )
    for col, run in enumerate(runs):
        x, y, w, _ = lay.panel(0, col)
        length = run.sample.length
        header = (
            f"({COLUMN_LETTERS.get(length, '?')}) {length}: guest boundary "
            f"{run.sample.boundary_ratio:.2f} x the host's"
        )
        draw.text(
            (x + w // 2, lay.title_height + lay.header_height // 2),
            header,
            fill=_TEXT,
            font=font,
            anchor="mm",
        )
        for row, caption in enumerate(_captions(run)):
            px, py, _, _ = lay.panel(row, col)
            mid = py - lay.caption_height // 2
            draw.text((px + fs // 3, mid), caption, fill=_DIM, font=small, anchor="lm")
    for row, label in enumerate(ROW_LABELS):
        _, y, _, h = lay.panel(row, 0)
        _vertical_text(img, label, (0, y, lay.label_width, h), small, background)
    # thin separators between the cells (a cell is a caption strip and its panel)
    grid = tuple(min(255, c + 40) for c in background)
    top = lay.title_height + lay.header_height
    for col in range(1, lay.columns):
        x = lay.panel(0, col)[0]
        draw.line([(x, top), (x, lay.size[1])], fill=grid)
    for row in range(1, lay.rows):
        y = lay.panel(row, 0)[1] - lay.caption_height
        draw.line([(lay.label_width, y), (lay.bar[0], y)], fill=grid)
    colour_bar(img, lay.bar, fs, limit, (float(np.nanmin(data)), float(np.nanmax(data))))
    return img


def paper_figures(runs: Sequence[Any], out_dir: str | os.PathLike) -> dict[str, Path]:
    """Write the paper's Figs. 2 and 3 from the demo's runs as PNG files.

    Parameters
    ----------
    runs : sequence of igljoin.demo.SampleRun
        The demo's joins (:func:`igljoin.demo.run_samples`): each sample
        without (``plain``) and with (``smooth``) the smooth-join term.
    out_dir : str or os.PathLike
        Existing folder for ``figure_end_to_end.png`` and
        ``figure_partial_patch.png`` (each written atomically).

    Returns
    -------
    dict of str to pathlib.Path
        ``"figure_end_to_end"`` and ``"figure_partial_patch"`` (a scenario
        without runs gets no figure).

    Examples
    --------
    >>> from igljoin import demo
    >>> runs = demo.run_samples(resolution=0.4, progress=False)  # doctest: +SKIP
    >>> paper_figures(runs, "out")  # doctest: +SKIP
    {'figure_end_to_end': PosixPath('out/figure_end_to_end.png'), ...}
    """
    out = Path(out_dir)
    written = {}
    for key, (scenario, title) in FIGURES.items():
        by_length = {r.sample.length: r for r in runs if r.sample.scenario == scenario}
        columns = [by_length[k] for k in LENGTHS if k in by_length]
        columns += [r for k, r in sorted(by_length.items()) if k not in LENGTHS]
        if not columns:
            continue
        image = paper_figure(columns, title)
        target = out / f"{key}.png"
        with atomic_path(target) as tmp:
            image.save(tmp, format="PNG")
        written[key] = target
    return written


#: Columns of the end-to-side figure: the whole graft, then each seam close up.
END_TO_SIDE_COLUMNS = ("whole graft, seen across its plane", "seam 0 close up", "seam 1 close up")
#: Panel size of the end-to-side figure (width, height), pixels.
END_TO_SIDE_PANEL = (420, 340)
#: Half the width a seam close-up frames, in the seam's own extent (its host curve's size).
END_TO_SIDE_CLOSEUP = 1.6
#: Field of view of the end-to-side panels (degrees): narrow, so the profiles are little distorted.
END_TO_SIDE_FOV_DEG = 30.0


def _profile_camera(
    target: np.ndarray, half_width: float, aspect: float, side: np.ndarray, up: np.ndarray
) -> Camera:
    """Looking at ``target`` along ``-side``, framing ``half_width`` across the panel."""
    half = half_width / max(min(aspect, 1.0), 1e-9)
    dist = half / np.tan(np.radians(END_TO_SIDE_FOV_DEG) / 2.0)
    return Camera(position=target + dist * side, target=target, up=up, fov_deg=END_TO_SIDE_FOV_DEG)


def end_to_side_figure(cases: Sequence[tuple[str, Any]], title: str = "") -> Any:
    """Draw end-to-side joins of a graft sewn at two seams, one row per join.

    Every panel looks across the plane through both seams' centres that holds
    the first seam's wall normal (a bypass graft's plane), so that each
    seam is seen in profile: the angle at which the graft leaves each wall is
    the angle drawn. Columns: the whole graft, then each seam close up
    (:data:`END_TO_SIDE_CLOSEUP` times its host curve's extent). Guests are
    coloured by area ratio on one scale for the figure.

    Parameters
    ----------
    cases : sequence of (str, JoinResult)
        A caption and a join with two seams (e.g. of
        :func:`igljoin.phantoms.bypass_graft_sample`), one per row.
    title : str

    Returns
    -------
    PIL.Image.Image
    """
    if not cases or any(len(res.seams) != 2 for _, res in cases):
        raise OptionsError("end_to_side_figure needs (caption, result) pairs of two-seam joins")
    pillow()  # fail early, before polyscope starts, if Pillow is missing
    ensure_init(headless=True)
    pw, ph = END_TO_SIDE_PANEL
    fs = 16
    title_h, header_h, caption_h, bar_w = round(3.6 * fs), round(1.8 * fs), round(1.7 * fs), 150
    rows = len(cases)
    size = (3 * pw + bar_w, title_h + header_h + rows * (caption_h + ph))
    limit = scale([res.area_ratio for _, res in cases])
    data = np.concatenate([res.area_ratio for _, res in cases])
    font, small = fonts(fs)
    shots, background = [], None
    for row, (_, res) in enumerate(cases):
        X = res.guest.V
        centre = X.mean(axis=0)
        ends = [res.host.V[sm.host_curve] for sm in res.seams]
        chord = ends[1].mean(axis=0) - ends[0].mean(axis=0)
        chord /= np.linalg.norm(chord)
        wall = np.linalg.svd(ends[0] - ends[0].mean(axis=0), full_matrices=False)[2][2]
        side = np.cross(chord, wall)
        side /= np.linalg.norm(side)
        up = np.cross(side, chord)  # the chord between the seams runs left to right
        box = _bounds(res.host, res.guest)
        cams = [_profile_camera(centre, 0.6 * float(np.ptp(X @ chord)), pw / ph, side, up)]
        for sm in res.seams:
            P = res.host.V[sm.host_curve]
            cams.append(
                _profile_camera(
                    P.mean(axis=0),
                    END_TO_SIDE_CLOSEUP * 0.5 * float(np.linalg.norm(np.ptp(P, axis=0))),
                    pw / ph,
                    side,
                    up,
                )
            )
        face = colors.area_colors(res.area_ratio, limit)
        for col, cam in enumerate(cams):
            rgb, background = render_meshes(res.host, res.guest, face, cam, (pw, ph), bounds=box)
            y = title_h + header_h + row * (caption_h + ph) + caption_h
            shots.append(((col * pw, y), rgb))
    img, draw = _canvas(
        size,
        background,
        shots,
        title,
        "Seen across the graft's plane, so each seam is in profile. Guest coloured by area "
        "ratio (deformed / rest): blue shrink, white no change, red stretch. Host in grey-green.",
        fs,
    )
    for col, header in enumerate(END_TO_SIDE_COLUMNS):
        draw.text(
            (col * pw + pw // 2, title_h + header_h // 2),
            header,
            fill=_TEXT,
            font=font,
            anchor="mm",
        )
    for row, (caption, res) in enumerate(cases):
        y = title_h + header_h + row * (caption_h + ph) + caption_h // 2
        si = res.metrics.get("self_intersections", {}).get("pairs")
        angles = ", ".join(f"{sm.crease.mean():.1f}\u00b0" for sm in res.seams)
        text = (
            f"{caption}: mean angle at the seams {angles}; "
            f"self-intersecting pairs {si}, folded pairs {res.metrics.get('folded_pairs')}"
        )
        draw.text((fs // 3, y), text, fill=_DIM, font=small, anchor="lm")
    grid = tuple(min(255, c + 40) for c in background)
    for col in (1, 2):
        draw.line([(col * pw, title_h), (col * pw, size[1])], fill=grid)
    bar = (3 * pw, title_h + header_h, bar_w, size[1] - title_h - header_h)
    colour_bar(img, bar, fs, limit, (float(np.nanmin(data)), float(np.nanmax(data))))
    return img
