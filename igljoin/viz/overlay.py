"""Title line and colour bar composited around rendered views with Pillow.

Polyscope cannot draw text or colour bars into screenshots reliably, so the
3D views are rendered into panels and placed on a canvas with a title band
on top and a colour bar on the right. Fonts are Pillow's built-in ones:
the same input gives the same pixels on every machine with the same Pillow.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from . import colors
from ._backend import pillow

__all__ = [
    "Layout",
    "colour_bar",
    "compose",
    "figures_line",
    "fonts",
    "layout",
    "legend",
    "warnings_line",
]

#: Minimum picture size (width, height) that leaves room for the title and the colour bar.
MIN_SIZE = (320, 240)

_TEXT = (235, 235, 235)
_DIM = (170, 172, 178)
#: Colour of the warnings notice of a result that has quality warnings.
WARNING_COLOR = (255, 170, 60)


@dataclass(frozen=True)
class Layout:
    """Where things go on the canvas (pixels, origin top-left).

    Attributes
    ----------
    size : (int, int)
        Canvas width and height.
    font_size : int
    title_height : int
        Height of the title band.
    panels : list of (x, y, w, h)
        3D panels, left to right.
    bar : (x, y, w, h)
        Colour bar column.
    """

    size: tuple[int, int]
    font_size: int
    title_height: int
    panels: list[tuple[int, int, int, int]]
    bar: tuple[int, int, int, int]


def layout(size: tuple[int, int], n_panels: int) -> Layout:
    """Split a canvas into a title band, ``n_panels`` 3D panels and a colour bar column."""
    w, h = size
    fs = max(11, round(min(h / 44.0, w / 60.0)))
    title_h = int(2 * round(1.35 * fs) + 0.8 * fs)
    bar_w = max(6 * fs, w // 9)
    pw = (w - bar_w) // n_panels
    bar_w = w - n_panels * pw
    ph = h - title_h
    panels = [(k * pw, title_h, pw, ph) for k in range(n_panels)]
    return Layout((w, h), fs, title_h, panels, (n_panels * pw, title_h, bar_w, ph))


def fonts(size: int) -> tuple[Any, Any]:
    """Pillow's built-in font at ``size`` pixels and at 0.8 of it (the small font)."""
    ImageFont = pillow().ImageFont
    try:
        return ImageFont.load_default(size=size), ImageFont.load_default(size=round(size * 0.8))
    except TypeError:  # Pillow < 10.1 or without FreeType: fixed bitmap font
        f = ImageFont.load_default()
        return f, f


def _fmt(x: Any, spec: str) -> str:
    return "n/a" if x is None else format(x, spec)


#: Relative seam gap (in mean seam edges) below which the title says the seam is closed.
CLOSED_GAP = 1e-9


def seam_gap_text(gap: dict) -> str:
    """The seam gap for a title: rounding-level gaps are reported as closed.

    Gaps of a solved join are floating-point noise (~1e-16) that differs from
    run to run; printing them would make pictures of the same case differ.
    """
    rel, top = gap.get("relative_max"), gap.get("max")
    if rel is None or top is None:
        return "seam gap n/a"
    if rel < CLOSED_GAP:
        return "seam gap < 1e-9 seam edge"
    return f"seam gap max {top:.2g} ({rel:.2g} seam edge)"


def figures_line(result: Any) -> str:
    """Key figures of a result on one line (no timings: pictures stay reproducible)."""
    m = result.metrics
    crease = m.get("crease_deg", {})
    ratio = m.get("area_ratio", {})
    change = m.get("area_change", {})
    mean_change = change.get("mean")
    parts = [
        f"crease mean {_fmt(crease.get('mean'), '.2f')}\u00b0, max {_fmt(crease.get('max'), '.2f')}"
        "\u00b0",
        seam_gap_text(m.get("seam_gap", {})),
        f"area ratio {_fmt(ratio.get('min'), '.2f')} to {_fmt(ratio.get('max'), '.2f')}, "
        f"mean change {_fmt(None if mean_change is None else 100 * mean_change, '.1f')}%",
        f"{result.iterations} iterations{'' if result.converged else ' (not converged)'}",
    ]
    return "   \u00b7   ".join(parts)


def warnings_line(result: Any) -> str:
    """The result's quality warnings on one line: ``"no quality warnings"`` or their codes.

    Examples: ``"2 quality warnings: crease, folds"`` (``docs/warnings.md``
    says what each means; the report carries the messages).
    """
    codes = [w.code for w in getattr(result, "warnings", ())]
    if not codes:
        return "no quality warnings"
    return f"{len(codes)} quality warning{'s' if len(codes) != 1 else ''}: {', '.join(codes)}"


def _clipped(data_range: tuple, limit: float) -> tuple[float | None, float | None]:
    """The data's smallest and largest area ratio where they lie beyond the colour scale."""
    lo, hi = (v if v is not None and np.isfinite(v) and v > 0 else None for v in data_range)
    return (lo if lo is not None and lo < 1.0 / limit else None), (
        hi if hi is not None and hi > limit else None
    )


def colour_bar(
    img: Any, box: tuple[int, int, int, int], font_size: int, limit: float, data_range: tuple
) -> None:
    """Draw the area-ratio colour bar with its ticks into ``img`` (in place).

    The data's smallest and largest ratio are marked beside the bar. Where
    they lie beyond the scale (faces drawn at full colour although they
    changed more), the bar ends in a pointed cap of that full colour and the
    mark sits at the cap's tip, labelled with the true value and "clipped".

    Parameters
    ----------
    img : PIL.Image.Image
        RGB canvas.
    box : (int, int, int, int)
        ``x, y, width, height`` of the bar column (origin top-left).
    font_size : int
        Size of the bar's title; ticks use 0.8 of it.
    limit : float
        Area ratio at full red (``1 / limit`` at full blue).
    data_range : (float, float)
        Smallest and largest area ratio shown, marked beside the bar (``None`` skips a mark).
    """
    PIL = pillow()
    draw = PIL.ImageDraw.Draw(img)
    x, y, w, h = box
    fs = font_size
    font, small = fonts(fs)
    cap = max(6, int(0.9 * fs))  # height of a clipping cap
    top = y + int(3.2 * fs) + cap
    bottom = y + h - int(2.0 * fs) - cap
    bx0 = x + int(0.9 * fs)
    bx1 = bx0 + max(8, int(1.1 * fs))
    draw.text((x + int(0.5 * fs), y + int(0.4 * fs)), "area ratio", fill=_TEXT, font=font)
    draw.text((x + int(0.5 * fs), y + int(1.7 * fs)), "deformed / rest", fill=_DIM, font=small)
    t = 1.0 - 2.0 * np.arange(bottom - top) / max(bottom - top - 1, 1)
    rgb = np.round(colors.diverging(t) * 255).astype(np.uint8)
    gradient = np.repeat(rgb[:, None, :], bx1 - bx0 + 1, axis=1)
    img.paste(PIL.Image.fromarray(gradient), (bx0, top))
    draw.rectangle([bx0, top, bx1, bottom - 1], outline=_DIM)

    def row_of(tt: float) -> int:
        return int(round(top + (1.0 - tt) * 0.5 * (bottom - 1 - top)))

    ticks, values = colors.area_ticks(limit)
    for tt, v in zip(ticks, values):
        r = row_of(float(tt))
        draw.line([(bx1, r), (bx1 + 4, r)], fill=_TEXT)
        draw.text((bx1 + 7, r), f"{v:.3g}", fill=_TEXT, font=small, anchor="lm")
    low, high = _clipped(data_range, limit)
    mid = (bx0 + bx1) / 2
    for clipped, edge, tip, full in (
        (high, top - 1, top - cap, 1.0),
        (low, bottom, bottom + cap, -1.0),
    ):
        if clipped is None:
            continue
        colour = tuple(int(c) for c in np.round(colors.diverging(np.array([full]))[0] * 255))
        draw.polygon([(bx0, edge), (bx1, edge), (mid, tip)], fill=colour, outline=_DIM)
        draw.text((bx1 + 7, tip), f"{clipped:.3g} clipped", fill=_TEXT, font=small, anchor="lm")
    scale = np.log2(limit)
    for v, clipped, tip in ((data_range[0], low, bottom + cap), (data_range[1], high, top - cap)):
        if v is None or not np.isfinite(v) or v <= 0:
            continue
        r = tip if clipped is not None else row_of(float(np.clip(np.log2(v) / scale, -1.0, 1.0)))
        draw.polygon([(bx0 - 2, r), (bx0 - 8, r - 4), (bx0 - 8, r + 4)], fill=_TEXT)
    draw.text(
        (x + int(0.5 * fs), bottom + cap + int(0.75 * fs)), "marks: min/max", fill=_DIM, font=small
    )


#: What the tangent ticks tell, under the legend.
SEAM_NOTE = "ticks: tangents across the seam; aligned = smooth join"


def _wrap(draw: Any, text: str, font: Any, width: float) -> list[str]:
    """``text`` broken into lines no wider than ``width`` pixels (a long word stays whole)."""
    lines: list[str] = []
    line = ""
    for word in text.split():
        trial = f"{line} {word}".strip()
        if line and draw.textlength(trial, font=font) > width:
            lines.append(line)
            line = word
        else:
            line = trial
    return lines + ([line] if line else [])


#: Legend of the seam and its cross-seam tangents (label, colour) under the colour bar.
SEAM_LEGEND = (
    ("seam", colors.SEAM_COLOR),
    ("host tangent", colors.HOST_TANGENT_COLOR),
    ("guest tangent", colors.GUEST_TANGENT_COLOR),
)


def legend(
    img: Any,
    origin: tuple[int, int],
    font_size: int,
    entries: tuple = SEAM_LEGEND,
    note: str = SEAM_NOTE,
) -> int:
    """Draw a legend of coloured line samples and labels into ``img`` (in place).

    Parameters
    ----------
    img : PIL.Image.Image
    origin : (int, int)
        Top-left corner.
    font_size : int
        Labels use 0.8 of it.
    entries : tuple of (str, (float, float, float))
        Label and RGB in [0, 1] of each line sample.
    note : str
        A last line in dim text, wrapped to the width left of the canvas ("" for none).

    Returns
    -------
    int
        The row below the legend.
    """
    PIL = pillow()
    draw = PIL.ImageDraw.Draw(img)
    _, small = fonts(font_size)
    x, y = origin
    step = round(1.2 * font_size)
    swatch = max(10, font_size)
    for label, rgb in entries:
        colour = tuple(int(round(255 * c)) for c in rgb)
        r = y + step // 2
        draw.line([(x, r), (x + swatch, r)], fill=colour, width=max(2, font_size // 5))
        draw.text((x + swatch + 5, r), label, fill=_TEXT, font=small, anchor="lm")
        y += step
    for line in _wrap(draw, note, small, img.size[0] - x - 4):
        draw.text((x, y), line, fill=_DIM, font=small)
        y += step
    return y


def compose(
    views: list[np.ndarray],
    lay: Layout,
    *,
    title: str,
    subtitle: str,
    captions: list[str],
    limit: float,
    data_range: tuple,
    background: tuple | None = None,
    seam_legend: bool = True,
    notice: str = "",
    alert: bool = False,
) -> Any:
    """Place rendered RGB views on a canvas with the title band, colour bar and legend.

    Parameters
    ----------
    views : list of ndarray of uint8, shape (h, w, 3)
        One image per panel of ``lay``.
    lay : Layout
    title, subtitle : str
        Title line (case name) and figures line.
    captions : list of str
        Small caption in each panel's top-left corner.
    limit : float
        Area ratio at full colour.
    data_range : (float, float)
        Smallest and largest area ratio, marked on the bar.
    background : (int, int, int), optional
        Canvas colour (default :data:`igljoin.viz.colors.BACKGROUND`); give the
        panels' rendered background so that bands and panels match exactly.
    seam_legend : bool
        Explain the seam and its tangent ticks (:data:`SEAM_LEGEND`) under
        the colour bar, where the column has room for it.
    notice : str
        Drawn on the title line after the title (the quality warnings,
        :func:`warnings_line`); "" for none.
    alert : bool
        Draw ``notice`` in :data:`WARNING_COLOR` instead of dim text.

    Returns
    -------
    PIL.Image.Image
        RGB image of size ``lay.size``.
    """
    PIL = pillow()
    bg = background or tuple(int(round(255 * c)) for c in colors.BACKGROUND)
    img = PIL.Image.new("RGB", lay.size, bg)
    for (x, y, _, _), view in zip(lay.panels, views):
        img.paste(PIL.Image.fromarray(np.ascontiguousarray(view)), (x, y))
    draw = PIL.ImageDraw.Draw(img)
    font, small = fonts(lay.font_size)
    fs = lay.font_size
    draw.text((int(0.6 * fs), int(0.4 * fs)), title, fill=_TEXT, font=font)
    if notice:
        x = int(0.6 * fs) + draw.textlength(title, font=font) + 1.5 * fs
        draw.text((x, int(0.4 * fs)), notice, fill=WARNING_COLOR if alert else _DIM, font=font)
    draw.text((int(0.6 * fs), int(0.4 * fs) + round(1.35 * fs)), subtitle, fill=_DIM, font=small)
    for (x, y, _, _), caption in zip(lay.panels, captions):
        draw.text((x + int(0.6 * fs), y + int(0.3 * fs)), caption, fill=_DIM, font=small)
    bx, by, bw, bh = lay.bar
    step = round(1.2 * fs)
    left = bx + int(0.5 * fs)
    note = _wrap(draw, SEAM_NOTE, small, lay.size[0] - left - 4)
    rows = len(SEAM_LEGEND) + len(note) + 1  # entries, the wrapped note, a gap above
    labels = max(draw.textlength(label, font=small) for label, _ in SEAM_LEGEND)
    words = max(draw.textlength(line, font=small) for line in note)
    room = lay.size[0] - left - 4  # to the canvas edge
    fits = max(max(10, fs) + 5 + labels, words) <= room and bh >= 12 * fs + rows * step
    if seam_legend and fits:
        colour_bar(img, (bx, by, bw, bh - rows * step), fs, limit, data_range)
        legend(img, (left, by + bh - (rows - 1) * step), fs)
    else:
        colour_bar(img, lay.bar, fs, limit, data_range)
    return img
