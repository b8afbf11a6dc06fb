"""Quality warnings (igljoin.quality): each code fires on a bad join and not on a clean one.

The clean joins are the paper's six samples with the default options. Each
bad join is built for one fault: the paper's "without smooth join" variant
(a crease), a patch twice the size of its hole (folds, self-intersections,
gross area change), a solve cut short (not converged), a patch whose seam
has a sliver or very uneven segments (made by splitting seam edges of the
paper's patch). A weld that fails is a re-solve with its seam targets
moved off the host curve. Faults no sample has yet (a host creased along the
seam, a total area change alone) are results whose metrics are set, tested
through :func:`igljoin.quality.assess`. Then every place a
result is shown carries the warnings: ``report()``, ``report.json``,
``summary.csv``/``summary.json``, ``igljoin join``/``batch``/``render`` and
the viewer's panel and pictures.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json

import numpy as np
import pytest

import igljoin
from igljoin import phantoms, quality
from igljoin.quality import CODES, QualityWarning, assess

from .cli_run import call as run


def _join(s, **options):
    return igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, **options)


def _codes(result) -> list[str]:
    return [w.code for w in result.warnings]


def _with_metrics(result, **changes):
    """A copy of ``result`` with some metrics replaced (its warnings are not yet computed)."""
    metrics = {**result.metrics, **changes}
    return dataclasses.replace(result, metrics=metrics)


def _split_seam_edges(mesh: igljoin.Mesh, splits: dict) -> igljoin.Mesh:
    """``mesh`` with boundary edges split at given parameters (faces fanned from the third vertex).

    ``splits`` maps a boundary edge ``(a, b)`` to the increasing parameters in
    (0, 1) of the new vertices from ``a`` to ``b``. Original vertices keep
    their indices; the new ones come after.
    """
    V, F = mesh.V.copy(), mesh.F.copy()
    new_V, keep, fans = [V], np.ones(len(F), dtype=bool), []
    n = len(V)
    for (a, b), ts in splits.items():
        # the face holding the edge, and its direction there
        for u, w in ((a, b), (b, a)):
            hit = np.flatnonzero(((F == u) & (np.roll(F, -1, axis=1) == w)).any(axis=1))
            if len(hit):
                break
        assert len(hit) == 1, "not a boundary edge"
        f = hit[0]
        c = int(next(x for x in F[f] if x not in (a, b)))
        t = np.asarray(ts if u == a else [1 - x for x in ts][::-1], dtype=np.float64)
        P = V[u] + t[:, None] * (V[w] - V[u])
        ids = list(range(n, n + len(P)))
        n += len(P)
        new_V.append(P)
        chain = [u, *ids, w]
        fans.extend([chain[i], chain[i + 1], c] for i in range(len(chain) - 1))
        keep[f] = False
    return igljoin.Mesh(
        np.vstack(new_V), np.vstack([F[keep], np.array(fans, dtype=np.int64)]), name="split guest"
    )


# --------------------------------------------------------------------------- joins


@pytest.fixture(scope="module")
def clean():
    """The paper's six samples joined with the default options: clean joins."""
    return {s.name: _join(s) for s in phantoms.paper_samples()}


@pytest.fixture(scope="module")
def patch():
    return phantoms.paper_sample("partial_patch", "equal", resolution=0.5)


@pytest.fixture(scope="module")
def rejoined(clean):
    """The paper's patch joined once, then joined again from there: inputs that meet smoothly.

    The samples' guests arrive at an angle (the flat patch meets the curved
    wall at a crease), which ``host_creased`` reports once the inputs' crease
    is measured; a guest already joined meets the host smoothly, so this join
    is clean of every code.
    """
    first = clean["partial_patch/equal"]
    return igljoin.join(first.host, first.guest, first.host_curve, None)


@pytest.fixture(scope="module")
def oversized(patch):
    """The paper's patch at twice its size: squeezed into the hole it folds and intersects."""
    c = patch.guest.V.mean(axis=0)
    big = igljoin.Mesh(c + 2.0 * (patch.guest.V - c), patch.guest.F, name="patch x2")
    return igljoin.join(patch.host, big, patch.host_curve, None)


@pytest.fixture(scope="module")
def unsmoothed():
    """The paper's end-to-end join without the smooth-join term: a 30-degree kink at the seam."""
    return _join(phantoms.paper_sample("end_to_end", "equal"), smooth=False)


@pytest.fixture(scope="module")
def cut_short(patch):
    return _join(patch, max_iterations=3)


@pytest.fixture(scope="module")
def off_seam(patch):
    """The patch re-solved with its seam targets moved off the host curve: it cannot be welded."""
    solver = igljoin.JoinSolver(patch.host, patch.guest, patch.host_curve, None)
    first = solver.solve()
    return solver.solve(targets=first.seam_targets + [0.0, 0.0, 0.25])


@pytest.fixture(scope="module")
def sliver(patch):
    """The patch with one seam edge split 3 % from its end, as a plane clip leaves it."""
    guest = _split_seam_edges(patch.guest, {(0, 1): [0.03]})
    return igljoin.join(patch.host, guest, patch.host_curve, None)


@pytest.fixture(scope="module")
def uneven(patch):
    """The patch with all but 20 seam edges split in six: those 20 are 6x the median."""
    n_b = len(igljoin.boundary_loops(patch.guest.F)[0])
    splits = {(i, (i + 1) % n_b): [k / 6 for k in range(1, 6)] for i in range(20, n_b)}
    guest = _split_seam_edges(patch.guest, splits)
    return igljoin.join(patch.host, guest, patch.host_curve, None)


@pytest.fixture(scope="module")
def bunny_cut():
    """A piece cut out of the real bunny (the first clean cut of tests/test_ground_truth.py)."""
    from .cuts import cut_piece, sample_mesh_dir

    bunny = igljoin.read_mesh(sample_mesh_dir() / "bunny.obj")
    rng = np.random.default_rng(1)
    size = float(np.linalg.norm(np.ptp(bunny.V, axis=0)))
    while True:
        cut = cut_piece(bunny, int(rng.integers(bunny.n_vertices)), size * rng.uniform(0.05, 0.2))
        if cut is not None:
            return cut


@pytest.fixture(scope="module")
def triggered(clean, oversized, unsmoothed, cut_short, off_seam, sliver, uneven):
    """Per code, a result that must carry it."""
    base = clean["partial_patch/equal"]
    return {
        "not_converged": cut_short,
        "crease": unsmoothed,
        # a result that kept a 20-degree crease the inputs already met at (a ridge of the
        # host along the seam; the corpus's wing tip is the real case, tests/test_corpus.py)
        "host_creased": _with_metrics(
            base,
            crease_deg={"mean": 8.0, "max": 20.0, "min": 1.0, "beyond_noise_max": 16.0},
            input_crease_deg={"mean": 12.0, "max": 25.0, "min": 1.0, "beyond_noise_max": 21.0},
        ),
        "folds": oversized,
        "weld_failed": off_seam,
        "self_intersections": oversized,
        "area_change": oversized,
        "seam_slivers": sliver,
        "seam_uneven": uneven,
    }


# --------------------------------------------------------------------------- each code


def test_the_paper_samples_join_without_a_warning(clean, rejoined):
    assert len(clean) == 6
    # the samples' guests arrive at an angle (their inputs meet at 11-19 degrees), which
    # the join removes: no warning, the report's input_crease_deg says it
    for name, res in clean.items():
        assert res.metrics["input_crease_deg"]["max"] > quality.HOST_CREASE_DEG, name
        assert _codes(res) == [], name
    assert _codes(rejoined) == []


@pytest.mark.parametrize("code", CODES)
def test_each_code_fires_on_its_fault_and_crosses_its_threshold(triggered, code):
    found = {w.code: w for w in triggered[code].warnings}
    assert code in found, [w.code for w in triggered[code].warnings]
    w = found[code]
    assert isinstance(w, QualityWarning) and len(w.message) > 60  # says what and what to do
    if w.value is not None and w.threshold is not None:
        if code == "not_converged":  # all the iterations allowed were used
            assert w.value >= w.threshold
        elif code == "seam_slivers" or (code == "area_change" and w.value < 1):
            assert w.value < w.threshold
        else:
            assert w.value > w.threshold


@pytest.mark.parametrize("code", CODES)
def test_each_code_is_absent_on_the_clean_joins(clean, rejoined, code):
    # with the metric that triggers it present and harmless where a join lacks it
    calm = _with_metrics(rejoined, input_crease_deg={"mean": 0.5, "max": 3.0, "min": 0.0})
    results = [rejoined, calm, *clean.values()]
    assert [r for r in results if code in _codes(r)] == []


def test_the_codes_come_in_their_documented_order(oversized):
    codes = _codes(oversized)
    assert codes == sorted(codes, key=CODES.index)
    assert {"folds", "self_intersections", "area_change"} <= set(codes)


def test_the_figures_behind_the_faults(oversized, unsmoothed, cut_short, off_seam, sliver, uneven):
    m = oversized.metrics
    assert m["folded_pairs"] > 0 and m["self_intersections"]["pairs"] > 0
    assert m["area_ratio"]["min"] < 1 / quality.AREA_RATIO_FACE_LIMIT
    assert unsmoothed.metrics["crease_deg"]["max"] > quality.CREASE_MAX_DEG
    assert not cut_short.converged and cut_short.iterations == 3
    w = {x.code: x for x in cut_short.warnings}["not_converged"]
    assert w.value == 3 and w.threshold == 3 and "max_iterations" in w.message
    assert (
        off_seam.metrics["weld"]["ok"] is False and off_seam.metrics["self_intersections"] is None
    )
    w = {x.code: x for x in off_seam.warnings}["weld_failed"]
    assert off_seam.metrics["weld"]["error"] in w.message  # the weld's own advice is kept
    # the split joins themselves are sound: only the seam warning is raised
    assert _codes(sliver) == ["seam_slivers"]
    assert _codes(uneven) == ["seam_uneven"]
    w = {x.code: x for x in sliver.warnings}["seam_slivers"]
    # 0.03 of one segment over a median of one whole segment: 3 % (the inserted host points
    # are not the input's and are left out, else they would make slivers of their own)
    # 5 %: the patch's seam segments are equal to rounding (measured 1.000 of their median)
    assert w.value == pytest.approx(0.03, rel=0.05)


def test_a_sliver_on_a_real_cut_warns_and_the_uncut_seam_does_not(bunny_cut):
    cut = bunny_cut
    loop = igljoin.boundary_loops(cut.piece.F)[0]
    split = _split_seam_edges(cut.piece, {(int(loop[0]), int(loop[1])): [0.02]})
    plain = igljoin.join(cut.host, cut.piece, cut.host_curve, None)
    slivered = igljoin.join(cut.host, split, cut.host_curve, None)
    assert "seam_slivers" not in _codes(plain)
    w = {x.code: x for x in slivered.warnings}["seam_slivers"]
    assert w.value < quality.SEAM_SLIVER_FRACTION and "guest seam" in w.message
    # the bunny's own seam is even: its shortest segment is 0.7 of the median (measured)
    assert min(quality.segment_lengths(cut.host.V[cut.host_curve], True)) > 0.5 * np.median(
        quality.segment_lengths(cut.host.V[cut.host_curve], True)
    )


@pytest.mark.parametrize("name", ["cow.obj", "airplane.obj", "bunny10k_textured.obj"])
def test_real_cuts_along_mesh_edges_have_no_seam_warning(name):
    """Cuts of real meshes along their own edges: even enough (no sliver, not uneven)."""
    from .cuts import cut_piece, sample_mesh_dir

    mesh = igljoin.read_mesh(sample_mesh_dir() / name)
    rng = np.random.default_rng(3)
    size = float(np.linalg.norm(np.ptp(mesh.V, axis=0)))
    found = 0
    for _ in range(300):
        cut = cut_piece(mesh, int(rng.integers(mesh.n_vertices)), size * rng.uniform(0.05, 0.25))
        if cut is None:
            continue
        loop = igljoin.boundary_loops(cut.piece.F)[0]
        curves = [
            ("host curve", quality.segment_lengths(cut.host.V[cut.host_curve], True)),
            ("guest seam", quality.segment_lengths(cut.piece.V[loop], True)),
        ]
        # measured: shortest 0.30 to 0.86 of the median, longest 1.2 to 3.4 times it
        assert quality.curve_warnings(curves) == [], (name, cut.piece.n_vertices)
        found += 1
        if found == 5:
            break
    assert found == 5


def test_a_total_area_change_alone_warns(clean):
    base = clean["partial_patch/equal"]
    grown = _with_metrics(base, area_ratio={"min": 0.9, "mean": 2.4, "max": 3.5, "total": 2.5})
    w = {x.code: x for x in grown.warnings}["area_change"]
    assert w.value == 2.5 and w.threshold == quality.AREA_RATIO_TOTAL_LIMIT
    assert "total area" in w.message
    shrunk = _with_metrics(base, area_ratio={"min": 0.3, "mean": 0.4, "max": 0.9, "total": 0.4})
    w = {x.code: x for x in shrunk.warnings}["area_change"]
    assert w.value == 0.4 and w.threshold == 1 / quality.AREA_RATIO_TOTAL_LIMIT


def test_missing_or_null_metrics_raise_no_warning(oversized):
    bare = _with_metrics(
        oversized,
        crease_deg={"mean": None, "max": None},
        input_crease_deg=None,
        area_ratio={},
        folded_pairs=None,
        self_intersections={"pairs": None},
    )
    assert _codes(bare) == []


def test_warnings_are_computed_once_and_kept(clean):
    res = clean["end_to_end/equal"]
    assert res.warnings is res.warnings
    assert assess(res) == res.warnings


def test_a_warning_is_frozen_plain_json():
    w = QualityWarning("folds", "2 pairs folded", np.int64(2), 0)
    assert w.to_json() == {"code": "folds", "message": "2 pairs folded", "value": 2, "threshold": 0}
    assert QualityWarning("crease", "x", float("nan"), 10.0).to_json()["value"] is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        w.code = "crease"


def test_segment_lengths_of_open_and_closed_curves():
    P = np.array([[0.0, 0, 0], [3, 0, 0], [3, 4, 0]])
    assert quality.segment_lengths(P, closed=False).tolist() == [3.0, 4.0]
    assert quality.segment_lengths(P, closed=True).tolist() == [3.0, 4.0, 5.0]


# --------------------------------------------------------------------------- where they show


def test_report_and_report_json_carry_the_warnings(oversized, rejoined, tmp_path):
    rep = oversized.report()
    assert [w["code"] for w in rep["warnings"]] == _codes(oversized)
    assert set(rep["warnings"][0]) == {"code", "message", "value", "threshold"}
    assert rejoined.report()["warnings"] == []
    paths = oversized.save(tmp_path / "out")
    saved = json.loads(paths["report"].read_text(encoding="utf-8"))
    assert saved["warnings"] == json.loads(json.dumps(rep["warnings"]))


@pytest.fixture(scope="module")
def cases(tmp_path_factory, patch, clean):
    """Two case folders: the patch already joined (clean) and the patch at twice its size."""
    root = tmp_path_factory.mktemp("cases")
    c = patch.guest.V.mean(axis=0)
    guests = {
        "clean": clean["partial_patch/equal"].guest,  # already joined: meets the host smoothly
        "oversized": igljoin.Mesh(c + 2.0 * (patch.guest.V - c), patch.guest.F),
    }
    for name, guest in guests.items():
        case = root / name
        case.mkdir()
        igljoin.write_mesh(case / "host.ply", patch.host)
        igljoin.write_mesh(case / "guest.ply", guest)
        (case / "join.toml").write_text("[host_curve]\nloop = 0\n")
    return root


def test_cli_join_prints_each_warning(cases, tmp_path, oversized):
    case = cases / "oversized"
    proc = run(
        "join", case / "host.ply", case / "guest.ply", "-o", tmp_path / "o", "--host-loop", "0"
    )
    assert proc.returncode == 0, proc.stderr  # a warned join is still a join: exit 0
    assert f"warnings: {len(oversized.warnings)} (see docs/warnings.md)" in proc.stdout
    for w in oversized.warnings:
        assert f"    {w.code}: " in proc.stdout
    clean = cases / "clean"
    proc = run(
        "join", clean / "host.ply", clean / "guest.ply", "-o", tmp_path / "c", "--host-loop", "0"
    )
    assert "  warnings: none" in proc.stdout
    proc = run(
        "join", case / "host.ply", case / "guest.ply", "-o", tmp_path / "j", "--host-loop", "0",
        "--json",
    )  # fmt: skip
    doc = json.loads(proc.stdout)
    assert [w["code"] for w in doc["warnings"]] == _codes(oversized)
    assert doc["summary"]["warnings"] == ";".join(_codes(oversized))


def test_cli_render_prints_the_warnings(cases, tmp_path, oversized):
    pytest.importorskip("polyscope")
    proc = run("render", cases / "oversized", "-o", tmp_path / "o.png", "--size", "400", "300")
    assert proc.returncode == 0, proc.stderr
    assert f"warnings: {len(oversized.warnings)} (see docs/warnings.md)" in proc.stdout
    assert all(f"    {w.code}: {w.message}" in proc.stdout for w in oversized.warnings)


def test_cli_batch_summary_csv_and_json_carry_the_warnings(cases, tmp_path, oversized):
    out = tmp_path / "out"
    proc = run("batch", cases, "-o", out, "--workers", "1", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    n = len(oversized.warnings)
    assert "2 cases: 2 ok (1 with warnings), 0 failed" in proc.stdout
    assert f"  oversized: ok, {n} warnings: {', '.join(_codes(oversized))}" in proc.stdout
    assert "clean:" not in proc.stdout  # a clean case needs no line of its own
    rows = list(csv.DictReader(io.StringIO((out / "summary.csv").read_text(encoding="utf-8"))))
    shown = {r["name"]: r["warnings"] for r in rows}
    assert shown == {"clean": "", "oversized": ";".join(_codes(oversized))}
    doc = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert doc["warned"] == 1 and doc["warned_cases"] == ["oversized"]
    report = json.loads((out / "oversized" / "report.json").read_text(encoding="utf-8"))
    assert [w["code"] for w in report["warnings"]] == _codes(oversized)
    assert all(isinstance(w["message"], str) and w["message"] for w in report["warnings"])


def test_batch_message_names_the_warned_cases():
    from igljoin.pipeline import BatchSummary

    rows = [
        {"name": "a", "status": "ok", "warnings": None},
        {"name": "b", "status": "ok", "warnings": "crease;folds"},
        {"name": "c", "status": "failed", "warnings": None},
    ]
    s = BatchSummary(out_dir=None, rows=rows)
    assert s.warned == ["b"]
    assert s.message() == "1 of 3 cases failed: c; 1 with warnings: b"
    assert BatchSummary(out_dir=None, rows=rows[:2]).message() == (
        "all 2 cases ok; 1 with warnings: b"
    )
    assert BatchSummary(out_dir=None, rows=rows[:1]).message() == "the case is ok"


def test_warning_codes_read_old_and_new_reports():
    from igljoin.pipeline import warning_codes

    assert warning_codes({"warnings": [{"code": "crease"}, "no snapshot: x"]}) == [
        "crease",
        "no snapshot: x",
    ]
    assert warning_codes({"warnings": None}) == warning_codes(None) == []


# --------------------------------------------------------------------------- the viewer


@pytest.fixture(scope="module")
def viz():
    pytest.importorskip("polyscope")
    pytest.importorskip("PIL")
    import igljoin.viz

    return igljoin.viz


def test_picture_title_line_shows_the_warnings(viz, oversized, rejoined):
    pic = viz.picture(oversized, size=(800, 500), title="oversized")
    assert pic.warnings == f"{len(oversized.warnings)} quality warnings: " + ", ".join(
        _codes(oversized)
    )
    rgb = np.asarray(pic.image.convert("RGB")).astype(int)
    band = rgb[: rgb.shape[0] // 12]  # the title band
    orange = np.abs(band - np.array(viz.overlay.WARNING_COLOR)).sum(axis=2) < 30  # anti-aliasing
    assert orange.sum() > 50  # the notice's glyphs (a few hundred pixels at this size)
    calm = viz.picture(rejoined, size=(800, 500), title="clean")
    assert calm.warnings == "no quality warnings"
    rgb = np.asarray(calm.image.convert("RGB")).astype(int)
    band = rgb[: rgb.shape[0] // 12]
    assert (np.abs(band - np.array(viz.overlay.WARNING_COLOR)).sum(axis=2) < 30).sum() == 0


def test_viewer_panel_lists_the_warnings(viz, oversized, rejoined):
    import polyscope as ps

    session = viz.inspect(oversized, show=False, title="oversized")
    try:
        lines = session.warnings()
        assert lines[0] == f"{len(oversized.warnings)} quality warnings:"
        assert lines[1:] == [f"{w.code}: {w.message}" for w in oversized.warnings]
        before = session.frames
        ps.frame_tick()  # draws the panel, warnings included
        assert session.frames == before + 1 and session.message == ""
    finally:
        session.close()
    session = viz.inspect(rejoined, show=False, title="clean")
    try:
        assert session.warnings() == ["no quality warnings"]
    finally:
        session.close()


# --------------------------------------------------------------------------- the docs


def test_docs_list_every_code_with_its_threshold():
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "warnings.md").read_text("utf-8")
    for code in (*CODES, "no_snapshot"):
        assert f"| `{code}` |" in page, code
    for name in (
        "CREASE_MAX_DEG",
        "HOST_CREASE_DEG",
        "AREA_RATIO_FACE_LIMIT",
        "AREA_RATIO_TOTAL_LIMIT",
        "SEAM_SLIVER_FRACTION",
        "SEAM_UNEVEN_RATIO",
    ):
        value = getattr(quality, name)
        unit = "°" if name.endswith("_DEG") else ""
        assert f"| `{name}` | {value:g}{unit} |" in page, name


def test_a_join_at_an_angle_is_judged_by_the_angle_asked_for():
    s = phantoms.paper_sample("end_to_end", "equal", resolution=0.5)
    asked = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, join_angle=20.0)
    # a 20-degree crease asked for and met (issue 19's bar: the mean within 2 degrees) is
    # no warning
    assert asked.metrics["crease_deg"]["mean"] > quality.CREASE_MAX_DEG
    assert asked.metrics["join_angle_error_deg"]["mean"] <= 2.0
    assert "crease" not in _codes(asked)
    # a smooth term too weak to turn the guest leaves it far from the angle: warned
    weak = igljoin.join(
        s.host, s.guest, s.host_curve, s.guest_curve, join_angle=60.0, smooth_weight=1e-4
    )
    assert weak.metrics["join_angle_error_deg"]["beyond_noise_max"] > quality.CREASE_MAX_DEG
    assert "crease" in _codes(weak)
