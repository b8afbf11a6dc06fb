"""The paper's experiments end to end: ``igljoin.demo.run`` and ``igljoin demo`` (issue: demo).

The demo is run once for the module at a reduced size (resolution 0.4: the six
joins take ~2 s instead of ~10 s) and its outputs are checked as a user would
see them: every file is there, the tables parse, the paper's claims are
checked, and the two figures are pictures of the right things. The command
line is run once at the paper's sizes, as ``make demo`` runs it (in this
process, through ``igljoin.cli.main``).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from igljoin import demo

pytest.importorskip("polyscope")
pytest.importorskip("PIL")
from PIL import Image  # noqa: E402

from igljoin.viz.figures import FIGURES, figure_layout, paper_figures  # noqa: E402

from .cli_run import call  # noqa: E402

#: Reduced phantom size for the module's demo run (1 = the paper's sizes).
RESOLUTION = 0.4
SCENARIOS = ("end_to_end", "partial_patch")
LENGTHS = ("shorter", "equal", "longer")
VARIANTS = ("with_smooth_join", "without_smooth_join")
RESULT_FILES = ("guest.ply", "merged.ply", "report.json")


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("demo")
    return out, demo.run(out, resolution=RESOLUTION, progress=False)


def _rgb(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB")).astype(np.int64)


def _masks(a: np.ndarray) -> dict[str, np.ndarray]:
    """Pixels that are clearly red, clearly blue, or light grey (a white surface, shaded).

    The margins (50 and 30 levels of 255) are far above what shading does to
    a grey surface or to the grey-green host (R - B < 15, G > R), so only the
    guest's area colours and the colour bar pass the red and blue tests.
    """
    R, G, B = a[..., 0], a[..., 1], a[..., 2]
    return {
        "red": (R - B > 50) & (R - G > 30),
        "blue": B - R > 50,
        "grey": (np.abs(R - G) < 12) & (np.abs(G - B) < 12) & (R > 150),
    }


def _in_panel(mask: np.ndarray, box: tuple[int, int, int, int]) -> int:
    x, y, w, h = box
    return int(mask[y : y + h, x : x + w].sum())


# --------------------------------------------------------------------------- files


def test_writes_every_file(run):
    out, result = run
    paths = result["paths"]
    assert result["notes"] == []  # the viz extra is installed here: no figure was skipped
    for key in ("table_md", "table_csv", "report", *FIGURES):
        assert Path(paths[key]).is_file(), key
        assert Path(paths[key]).stat().st_size > 0, key
    assert paths["figure_end_to_end"] == out / "figure_end_to_end.png"
    assert paths["figure_partial_patch"] == out / "figure_partial_patch.png"
    for scenario in SCENARIOS:
        for length in LENGTHS:
            for variant in VARIANTS:
                folder = out / scenario / length / variant
                for name in RESULT_FILES:
                    path = folder / name
                    assert path.is_file() and path.stat().st_size > 0, path
                report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
                assert isinstance(report, dict) and report
    # atomic writers leave no hidden temporary files behind
    assert not [p for p in out.rglob(".*")]


def test_table_csv_has_one_row_per_sample(run):
    out, _ = run
    with open(out / "table.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 6
    assert {(r["scenario"], r["length"]) for r in rows} == {
        (s, n) for s in SCENARIOS for n in LENGTHS
    }
    for r in rows:
        numbers = {k: float(v) for k, v in r.items() if k not in ("scenario", "length")}
        assert all(np.isfinite(v) for v in numbers.values()), r
        # a closed seam: gap at rounding level (1e-9 seam edges is a million times above it)
        assert numbers["seam_gap_rel"] < 1e-9, r


def test_report_json_matches_the_tables(run):
    out, result = run
    report = json.loads((out / "report.json").read_text(encoding="utf-8"))
    assert report["resolution"] == RESOLUTION
    assert len(report["rows"]) == 6 and len(report["samples"]) == 6
    assert [c["claim"] for c in report["claims"]] == [c["claim"] for c in result["claims"]]
    assert len(report["claims"]) == 4


def test_claims_hold_at_reduced_size(run):
    """The smoothness, stretch and minimal-deformation claims hold at resolution 0.4."""
    out, _ = run
    claims = json.loads((out / "report.json").read_text(encoding="utf-8"))["claims"]
    for c in claims[:3]:
        assert c["confirmed"], c


@pytest.mark.xfail(
    strict=True,
    reason=(
        "at resolution < 0.8 the longer partial patch shrinks below the claim's 0.9 total area "
        "ratio (0.83 at 0.4, 0.90 at 0.8, 0.92 at 1; the same with the committed solver); "
        "confirmed at the paper's sizes, see test_cli_demo_at_paper_sizes"
    ),
)
def test_all_claims_confirmed_at_reduced_size(run):
    out, _ = run
    claims = json.loads((out / "report.json").read_text(encoding="utf-8"))["claims"]
    table = (out / "table.md").read_text(encoding="utf-8")
    assert all(c["confirmed"] for c in claims), [c["evidence"] for c in claims]
    assert "NOT confirmed" not in table
    assert table.count("confirmed") == 4


# --------------------------------------------------------------------------- figures


@pytest.mark.parametrize("key", list(FIGURES))
def test_figure_is_the_paper_layout_and_not_blank(run, key):
    out, _ = run
    a = _rgb(out / f"{key}.png")
    lay = figure_layout()
    assert a.shape == (lay.size[1], lay.size[0], 3)
    # a rendered figure has shading gradients in every panel: thousands of colours (measured
    # 13,000 to 25,000); a blank or flat-coloured canvas has a few dozen (text anti-aliasing)
    assert len(np.unique(a[..., 0] * 65536 + a[..., 1] * 256 + a[..., 2])) > 5000
    m = _masks(a)
    for col in range(3):
        # row 1 is the undeformed guest, white on the colour scale: drawn (a grey surface of at
        # least 1,000 pixels; measured 9,000 to 67,000) and free of red and blue
        assert _in_panel(m["grey"], lay.panel(0, col)) > 1000, (key, col)
        assert _in_panel(m["red"], lay.panel(0, col)) == 0, (key, col)
        assert _in_panel(m["blue"], lay.panel(0, col)) == 0, (key, col)
    for row in (1, 2, 3):
        # rows 2-4 show the joined guests: the shorter guest is stretched near the seam (the
        # smallest red area, the seam band of the end-to-end join, measured 190 to 3,000
        # pixels; 100 is well above anything but the area colours)
        red = sum(_in_panel(m["red"], lay.panel(row, col)) for col in range(3))
        assert red >= 100, (key, row, red)
    # the longer guest shrinks at the seam: blue in its column (rows 2-4 together measured 700
    # to 5,000 pixels)
    blue = sum(_in_panel(m["blue"], lay.panel(row, 2)) for row in (1, 2, 3))
    assert blue >= 200, (key, blue)
    # the colour bar carries both ends of the scale
    assert _in_panel(m["red"], lay.bar) > 1000 and _in_panel(m["blue"], lay.bar) > 1000


@pytest.fixture(scope="module")
def runs_again() -> list:
    """The six samples joined a second time in this process (as the module's demo run did)."""
    return demo.run_samples(RESOLUTION, progress=False)


def test_figures_are_deterministic(run, runs_again, tmp_path):
    """Joining again and drawing again gives the same bytes (no timings, no state carried)."""
    out, _ = run
    again = paper_figures(runs_again, tmp_path)
    assert set(again) == set(FIGURES)
    for key, path in again.items():
        assert path.read_bytes() == (out / f"{key}.png").read_bytes(), key


# --------------------------------------------------------------------------- command line


def _cli_demo_available() -> str | None:
    """Why ``igljoin demo`` cannot be run, or None."""
    proc = call("demo", "--help")
    if proc.returncode != 0:
        return f"`igljoin demo` is not available yet: {proc.stderr.strip()[-200:]}"
    return None


@pytest.mark.slow
def test_cli_demo_at_paper_sizes(tmp_path):
    """``igljoin demo --out DIR`` as ``make demo`` runs it: everything written, claims confirmed."""
    why = _cli_demo_available()
    if why:
        pytest.skip(why)
    out = tmp_path / "demo"
    proc = call("demo", "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    report = json.loads((out / "report.json").read_text(encoding="utf-8"))
    assert report["resolution"] == 1.0
    assert all(c["confirmed"] for c in report["claims"]), [c["evidence"] for c in report["claims"]]
    table = (out / "table.md").read_text(encoding="utf-8")
    assert table.count("confirmed") == 4 and "NOT confirmed" not in table
    lay = figure_layout()
    for key in FIGURES:
        a = _rgb(out / f"{key}.png")
        assert a.shape == (lay.size[1], lay.size[0], 3)
        assert len(np.unique(a[..., 0] * 65536 + a[..., 1] * 256 + a[..., 2])) > 5000
    for scenario in SCENARIOS:
        for length in LENGTHS:
            for variant in VARIANTS:
                for name in RESULT_FILES:
                    assert (out / scenario / length / variant / name).is_file()


def test_render_meshes_names_the_colour_shape():
    """The bare-panel hook behind row 1 rejects colours that are not one RGB per guest face."""
    from igljoin import phantoms
    from igljoin.errors import OptionsError
    from igljoin.viz import Camera, render_meshes

    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.3)
    cam = Camera(np.array([40.0, 0.0, 0.0]), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    with pytest.raises(
        OptionsError, match=rf"guest_colors must have shape \({len(s.guest.F)}, 3\)"
    ):
        render_meshes(s.host, s.guest, np.ones((3, 3)), cam, (64, 64))
    rgb, background = render_meshes(s.host, s.guest, np.ones((len(s.guest.F), 3)), cam, (64, 48))
    assert rgb.shape == (48, 64, 3) and rgb.dtype == np.uint8
    assert len(background) == 3


def test_demo_goes_beyond_the_paper(run):
    """The end-to-side bypass (two seams, one solve) and the stiff-half patch are in the demo."""
    out, result = run
    report = json.loads((out / "report.json").read_text())
    extra = report["beyond_the_paper"]
    bypass, patch = extra["bypass_graft"], extra["stiff_patch"]
    assert [j["join_angle_deg"] for j in bypass["joins"]] == list(demo.BYPASS_JOIN_ANGLES)
    for j in bypass["joins"]:
        assert j["converged"]
        # the bounds: each seam's mean angle within 2 degrees of the one asked for,
        # no self-intersecting and no folded face pair, and no warning of either
        assert len(j["crease_mean_deg_per_seam"]) == 2
        assert all(abs(c - j["join_angle_deg"]) <= 2.0 for c in j["crease_mean_deg_per_seam"])
        assert j["self_intersecting_pairs"] == 0 and j["folded_pairs"] == 0
        assert not {"self_intersections", "folds"} & set(j["warnings"])
    # without room for a hood the graft crosses itself, and its warnings say so
    tight = bypass["no_hood"]
    assert tight["self_intersecting_pairs"] > 0
    assert {"self_intersections", "folds"} <= set(tight["warnings"])
    assert patch["converged"]
    # the bound: the 10x stiffer half changes at most half as much as the soft half
    assert patch["median_area_change_stiff"] <= 0.5 * patch["median_area_change_soft"]
    folders = [out / "bypass_graft" / f"join_angle_{a:g}" for a in demo.BYPASS_JOIN_ANGLES]
    for folder in folders + [out / "bypass_graft" / "no_hood", out / "stiff_patch"]:
        for f in ("guest.ply", "merged.ply", "report.json"):
            assert (folder / f).is_file(), folder / f
    for name in ("bypass_graft", "stiff_patch"):
        assert result["paths"][name].is_file()
    table = (out / "table.md").read_text()
    assert "Beyond the paper" in table
    assert table.count("self-intersecting face pairs") == len(bypass["joins"]) + 1


def test_table_reports_crossings_and_folds_per_sample(run):
    out, result = run
    with open(out / "table.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        # the paper's samples join without crossing or folding (the quality tests' clean joins)
        assert int(r["self_intersecting_pairs"]) == 0 and int(r["folded_pairs"]) == 0, r
    head = (out / "table.md").read_text().splitlines()
    assert any("| self-intersections | folds |" in line for line in head)


def test_bypass_picture_shows_each_join_in_a_row(run):
    from igljoin.viz.figures import END_TO_SIDE_PANEL

    out, _ = run
    a = _rgb(out / "bypass_graft.png")
    rows = len(demo.BYPASS_JOIN_ANGLES) + 1  # and the case without a hood
    pw, ph = END_TO_SIDE_PANEL
    assert a.shape[1] > 3 * pw and a.shape[0] > rows * ph
    # rendered, not blank: thousands of colours (a flat canvas with text has a few dozen)
    assert len(np.unique(a[..., 0] * 65536 + a[..., 1] * 256 + a[..., 2])) > 5000
    # the hoods are stretched: red guest faces in the panels, left of the colour bar (measured
    # 5,300 pixels; 2,000 is well above anti-aliased text, which is grey)
    assert _masks(a)["red"][:, : 3 * pw].sum() > 2000


def test_stiff_patch_picture_names_its_halves_on_a_scale_that_holds_them(run):
    from igljoin.viz.annotate import LABEL_BOX, OUTLINE

    out, result = run
    a = _rgb(out / "stiff_patch.png")
    summary = json.loads((out / "report.json").read_text())["beyond_the_paper"]["stiff_patch"]
    limit = summary["picture_area_ratio_limit"]
    # the soft half's typical face (median ratio 1.79 at the paper's size) is drawn below full
    # colour, so the half shows its gradation; the default scale (1.5) flattened it
    assert 1.0 + summary["median_area_change_soft"] < limit
    # the side panel (left half) carries the outline of the stiff half and two name labels
    left = a[:, : a.shape[1] // 2]
    assert (np.abs(left - np.array(OUTLINE)).max(axis=-1) == 0).sum() > 100
    assert (np.abs(left - np.array(LABEL_BOX)).max(axis=-1) == 0).sum() > 200


def test_partial_patch_close_up_shows_what_the_smooth_term_changes(runs_again):
    """The seam close-up of the figure's rows 2-3 tells the with/without joins apart."""
    from igljoin.viz import colors
    from igljoin.viz.figures import seam_closeup
    from igljoin.viz.headless import render_meshes

    longer = next(r for r in runs_again if r.sample.name == "partial_patch/longer")
    close, k = seam_closeup(longer)
    assert longer.plain.crease[k] == np.nanmax(longer.plain.crease)
    side = _column_side_camera(longer)
    changed = {}
    for name, cam in (("close-up", close), ("overview", side)):
        shots = [
            render_meshes(res.host, res.guest, colors.area_colors(res.area_ratio), cam, (200, 180))[
                0
            ]
            for res in (longer.plain, longer.smooth)
        ]
        diff = np.abs(shots[0].astype(np.int64) - shots[1]).sum(axis=-1) > 60
        changed[name] = diff.mean()
    # the kink without the term against the smooth join: a fifth of the close-up's pixels
    # change (0.21 measured at this size, 0.17 at the paper's), against 0.088 of the face-on
    # overview; half the measured fraction, and 1.5x the overview's, leave room for shading noise
    assert changed["close-up"] > 0.1 and changed["close-up"] > 1.5 * changed["overview"], changed


def _column_side_camera(r):
    from igljoin.viz.figures import _column_panels

    return _column_panels(r, 200 / 180, 2.0)[2][3]
