"""Case folders and join.toml (igljoin.spec): parsing, validation, confinement."""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

import igljoin
from igljoin import phantoms
from igljoin.spec import CaseSpec, discover_cases, file_sha256, load_case

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def sample():
    return phantoms.paper_sample("partial_patch", "equal", resolution=0.4)


def make_case(root: Path, sample, toml: str | None = "", name: str = "case") -> Path:
    folder = root / name
    folder.mkdir(parents=True)
    igljoin.write_mesh(folder / "host.ply", sample.host)
    igljoin.write_mesh(folder / "guest.obj", sample.guest)
    if toml is not None:
        (folder / "join.toml").write_text(toml, encoding="utf-8")
    return folder


def test_the_documented_examples_load(tmp_path, sample):
    doc = (ROOT / "docs" / "pipelines.md").read_text(encoding="utf-8")
    complete, resampled = re.findall(r"```toml\n(.*?)```", doc, re.S)
    folder = make_case(tmp_path, sample, complete)
    np.save(folder / "stiffness.npy", np.full(sample.guest.n_vertices, 2.0))
    spec = load_case(folder)
    assert spec.name == "case" and spec.host == folder.resolve() / "host.ply"
    assert spec.host_curve == igljoin.Curve(loop=0)
    np.testing.assert_array_equal(spec.guest_curve.start, [21.5, 0.25, 3.0])
    assert spec.options.smooth_weight == 10.0
    np.testing.assert_array_equal(spec.options.stiffness, 2.0)
    assert spec.stiffness_file == folder.resolve() / "stiffness.npy"
    assert spec.join_options().stiffness_on == "vertex"
    assert spec.cleanup.close_holes and spec.cleanup.max_hole_edges == 30
    assert set(spec.input_files()) == {"host", "guest", "spec", "stiffness"}
    spec = load_case(make_case(tmp_path, sample, resampled, "resampled"))
    assert spec.resample.target_edge is None and spec.resample.iterations == 10
    assert spec.guest_curve == igljoin.Curve(loop=0)


def test_defaults_without_join_toml(tmp_path, sample):
    spec = load_case(make_case(tmp_path, sample, toml=None))
    assert spec.spec_file is None and spec.host_curve == igljoin.Curve()
    assert spec.cleanup is None and spec.resample is None
    assert spec.join_options() == igljoin.JoinOptions()


def test_curves_in_every_form(tmp_path, sample):
    toml = (
        "[host_curve]\nindices = [0, 1, 2, 3]\nclosed = false\n\n"
        "[guest_curve]\nstart = 3\nend = [1.0, 2, 3.5]\nvia = 7\n"
    )
    spec = load_case(make_case(tmp_path, sample, toml))
    np.testing.assert_array_equal(spec.host_curve.indices, [0, 1, 2, 3])
    assert spec.host_curve.closed is False
    assert spec.guest_curve.start == 3 and spec.guest_curve.via == 7
    assert spec.guest_curve.end.dtype == np.float64


def test_options_shorthands(tmp_path, sample):
    toml = "[options]\ncleanup = true\nresample = 0.75\nsmooth = false\n"
    spec = load_case(make_case(tmp_path, sample, toml))
    assert spec.cleanup == igljoin.spec.CleanupSpec()
    assert spec.resample.target_edge == 0.75
    assert spec.join_options().smooth is False
    spec = load_case(make_case(tmp_path, sample, "[options.cleanup]\nenabled = false\n", "off"))
    assert spec.cleanup is None


@pytest.mark.parametrize(
    "toml, match",
    [
        ("hots = 'host.ply'\n", r"unknown keys 'hots'; valid keys are description, host, guest"),
        ("[host_curve]\nloops = 0\n", r"unknown curve keys 'loops'; valid keys are indices"),
        ("[options]\nsmoth = true\n", r"unknown options 'smoth'; valid keys are smooth, "),
        ("[options.cleanup]\nholes = true\n", r"unknown cleanup keys 'holes'.*close_holes"),
        ("[options.resample]\nedge = 1.0\n", r"unknown resample keys 'edge'.*target_edge"),
        ("[host_curve]\nloop = 'zero'\n", r"loop = 'zero' must be a loop index"),
        ("[host_curve]\nstart = [1, 2]\n", r"start = \[1, 2\] must be a vertex index"),
        ("[host_curve]\nindices = []\n", r"indices must be a non-empty list"),
        ("[host_curve]\nindices = [1, 2]\nstart = 1\n", r"either indices or start"),
        ("[options]\nsmooth_weight = -1.0\n", r"smooth_weight=-1.0 is out of range"),
        ("[options]\nstiffness = [1, 'a']\n", r"stiffness must be a list of numbers"),
        ("[options.resample]\ntarget_edge = -2\n", r"target_edge = -2 must be a positive"),
        ("host_curve = 3\n", r"\[host_curve\] must be a table"),
        ("description = 5\n", r"description must be a string"),
        ("[options\n", r"not valid TOML"),
    ],
)
def test_invalid_specs_name_the_problem(tmp_path, sample, toml, match):
    folder = make_case(tmp_path, sample, toml)
    with pytest.raises(igljoin.SpecError, match=match) as info:
        load_case(folder)
    assert "join.toml" in str(info.value)  # every message names the file


def test_spec_is_data_never_evaluated(tmp_path, sample):
    marker = tmp_path / "pwned"
    toml = f"[options]\nsmooth_mode = \"__import__('os').system('touch {marker}')\"\n"
    with pytest.raises(igljoin.SpecError, match="smooth_mode"):
        load_case(make_case(tmp_path, sample, toml))
    assert not marker.exists()


def test_resample_refuses_index_curves_and_stiffness(tmp_path, sample):
    folder = make_case(tmp_path, sample, "[guest_curve]\nstart = 4\n[options]\nresample = true\n")
    with pytest.raises(igljoin.SpecError, match="loop index or by points"):
        load_case(folder)
    folder = make_case(
        tmp_path, sample, "[options]\nresample = true\nstiffness = [1.0, 2.0]\n", "stiff"
    )
    with pytest.raises(igljoin.SpecError, match="resample remeshes the guest"):
        load_case(folder)
    # a loop index or points are fine
    folder = make_case(
        tmp_path,
        sample,
        "[guest_curve]\nstart = [1.0, 2.0, 3.0]\n[options]\nresample = true\n",
        "ok",
    )
    assert load_case(folder).resample is not None


# --------------------------------------------------------------------------- confinement


def test_paths_may_not_leave_the_case_folder(tmp_path, sample):
    other = make_case(tmp_path, sample, None, "other")
    for value in ("../other/host.ply", str(other / "host.ply")):
        folder = make_case(tmp_path, sample, f'host = "{value}"\n', f"c{len(value)}")
        with pytest.raises(igljoin.SpecError, match="outside the case folder") as info:
            load_case(folder)
        assert value in str(info.value) or repr(value) in str(info.value)


def test_symlinks_pointing_outside_are_refused(tmp_path, sample):
    other = make_case(tmp_path, sample, None, "other")
    folder = make_case(tmp_path, sample, None, "linked")
    (folder / "host.ply").unlink()
    os.symlink(other / "host.ply", folder / "host.ply")
    with pytest.raises(igljoin.SpecError, match=r"host.ply.*outside the case folder"):
        load_case(folder)
    # a stiffness file linked from outside, and a join.toml linked from outside
    folder = make_case(tmp_path, sample, '[options]\nstiffness = "k.npy"\n', "klink")
    np.save(other / "k.npy", np.ones(sample.guest.n_vertices))
    os.symlink(other / "k.npy", folder / "k.npy")
    with pytest.raises(igljoin.SpecError, match=r"'k.npy'.*outside the case folder"):
        load_case(folder)
    folder = make_case(tmp_path, sample, None, "speclink")
    (other / "join.toml").write_text("[host_curve]\nloop = 0\n")
    os.symlink(other / "join.toml", folder / "join.toml")
    with pytest.raises(igljoin.SpecError, match="outside the case folder"):
        load_case(folder)
    # a link that stays inside the folder is fine
    folder = make_case(tmp_path, sample, 'host = "h.ply"\n', "inside")
    os.symlink(folder / "host.ply", folder / "h.ply")
    assert load_case(folder).host == (folder / "host.ply").resolve()


def test_missing_and_ambiguous_meshes(tmp_path, sample):
    folder = make_case(tmp_path, sample, None)
    (folder / "guest.obj").unlink()
    with pytest.raises(igljoin.SpecError, match="no guest mesh"):
        load_case(folder)
    igljoin.write_mesh(folder / "guest.off", sample.guest)
    igljoin.write_mesh(folder / "guest.ply", sample.guest)
    with pytest.raises(igljoin.SpecError, match=r"several guest meshes \(guest.off, guest.ply\)"):
        load_case(folder)
    (folder / "join.toml").write_text('guest = "guest.ply"\nhost = "nope.ply"\n')
    with pytest.raises(igljoin.SpecError, match="'nope.ply': no such file"):
        load_case(folder)
    (folder / "join.toml").write_text('guest = "guest.ply"\n[options]\nstiffness = "k.json"\n')
    (folder / "k.json").write_text("[1]")
    with pytest.raises(igljoin.SpecError, match="unsupported suffix"):
        load_case(folder)


def test_stiffness_text_files(tmp_path, sample):
    folder = make_case(tmp_path, sample, '[options]\nstiffness = "k.csv"\n')
    k = np.linspace(1, 2, sample.guest.n_vertices)
    np.savetxt(folder / "k.csv", k[None], delimiter=",", fmt="%.17g")
    np.testing.assert_array_equal(load_case(folder).options.stiffness, k)
    (folder / "k.csv").write_text("1,2,oops\n")
    with pytest.raises(igljoin.SpecError, match="cannot read the stiffness file k.csv"):
        load_case(folder)


# --------------------------------------------------------------------------- identity


def test_spec_json_and_hashes_do_not_depend_on_the_folder_location(tmp_path, sample):
    a = make_case(tmp_path / "a", sample, "[host_curve]\nloop = 0\n")
    b = tmp_path / "elsewhere" / "deeper" / "case"
    shutil.copytree(a, b)
    sa, sb = load_case(a), load_case(b)
    assert sa.to_json() == sb.to_json()
    assert sa.input_hashes() == sb.input_hashes()
    assert sa.input_hashes()["host"] == {
        "file": "host.ply",
        "sha256": file_sha256(a / "host.ply"),
    }
    # every effective option is listed, defaults included
    assert sa.to_json()["options"] == igljoin.JoinOptions().to_json()


def test_discover_cases(tmp_path, sample):
    for name in ("b", "a", ".hidden", "_skip"):
        make_case(tmp_path, sample, None, name)
    (tmp_path / "notes").mkdir()
    (tmp_path / "readme.txt").write_text("x")
    assert [p.name for p in discover_cases(tmp_path)] == ["a", "b"]
    assert discover_cases(tmp_path / "a") == [tmp_path / "a"]  # a single case folder
    with pytest.raises(igljoin.SpecError, match="no case folders found"):
        discover_cases(tmp_path / "notes")
    with pytest.raises(igljoin.SpecError, match="not a folder"):
        discover_cases(tmp_path / "readme.txt")


def test_case_from_arguments(tmp_path, sample):
    folder = make_case(tmp_path, sample, None)
    spec = CaseSpec.make(
        folder / "host.ply",
        folder / "guest.obj",
        {"loop": 0},
        None,
        {"smooth": False, "cleanup": {"close_holes": True}},
    )
    assert spec.name == "guest" and spec.folder is None
    assert spec.host_curve.loop == 0 and spec.cleanup.close_holes
    with pytest.raises(igljoin.SpecError, match="unknown options 'bogus'"):
        CaseSpec.make(folder / "host.ply", folder / "guest.obj", options={"bogus": 1})


# --------------------------------------------------------------------------- options as objects


def test_case_holds_validated_option_objects(tmp_path, sample):
    toml = (
        "[options]\nsmooth_weight = 4.0\n[options.cleanup]\nclose_holes = true\n"
        "[options.resample]\niterations = 3\n"
    )
    spec = load_case(make_case(tmp_path, sample, toml))
    assert isinstance(spec.options, igljoin.JoinOptions) and spec.options.smooth_weight == 4.0
    assert spec.join_options() is spec.options
    assert spec.cleanup == igljoin.spec.CleanupSpec(close_holes=True)
    assert spec.resample == igljoin.spec.ResampleSpec(iterations=3)
    with pytest.raises(igljoin.SpecError, match="options must be a JoinOptions"):
        dataclasses.replace(spec, options={"smooth_weight": 4.0})


def test_cleanup_and_resample_defaults_are_the_functions_own():
    import inspect

    from igljoin.clean import clean, resample

    spec = igljoin.spec
    for kind, function in ((spec.CleanupSpec, clean), (spec.ResampleSpec, resample)):
        defaults = {
            name: p.default
            for name, p in inspect.signature(function).parameters.items()
            if p.default is not inspect.Parameter.empty
        }
        for f in dataclasses.fields(kind):
            if f.name in defaults:
                assert f.default == defaults[f.name], f.name


@pytest.mark.parametrize(
    "kind, settings, match",
    [
        ("CleanupSpec", {"max_hole_edges": 2}, r"max_hole_edges = 2 must be an integer from 3"),
        ("CleanupSpec", {"sliver_ratio": 1.0}, r"sliver_ratio = 1.0 must be a number in \[0, 1\)"),
        ("CleanupSpec", {"min_component_faces": -1}, r"min_component_faces = -1 must be"),
        ("CleanupSpec", {"host": "yes"}, r"host = 'yes' must be true or false"),
        ("ResampleSpec", {"iterations": 500}, r"iterations = 500 must be an integer from 1 to 100"),
        ("ResampleSpec", {"target_edge": "1.5"}, r"target_edge = '1.5' must be a positive length"),
        ("ResampleSpec", {"target_edge": float("nan")}, r"target_edge = nan must be a positive"),
    ],
)
def test_cleanup_and_resample_specs_validate_themselves(kind, settings, match):
    with pytest.raises(igljoin.OptionsError, match=match):
        getattr(igljoin.spec, kind)(**settings)


@pytest.mark.parametrize(
    "toml, match",
    [
        ("[options.cleanup]\nmax_hole_edges = 2.5\n", r"\[options.cleanup\] max_hole_edges = 2.5"),
        ("[options.resample]\niterations = 500\n", r"\[options.resample\] iterations = 500"),
        ("[options.resample]\ntarget_edge = 'x'\n", r"positive length or \"host_curve\""),
    ],
)
def test_spec_reports_the_objects_checks_with_the_file(tmp_path, sample, toml, match):
    with pytest.raises(igljoin.SpecError, match=match) as info:
        load_case(make_case(tmp_path, sample, toml))
    assert "join.toml" in str(info.value)


# ------------------------------------------------------------------- renamed options


@pytest.mark.parametrize(
    ("old", "new", "value"),
    [("tolerance", "energy_tolerance", 1e-3), ("snap_tolerance", "snap_fraction", 0.3),
     ("smooth_tolerance", "smooth_keep_deg", 5.0)],
)  # fmt: skip
def test_old_option_names_in_join_toml_warn_and_both_are_refused(tmp_path, sample, old, new, value):
    folder = make_case(tmp_path, sample, f"[options]\n{old} = {value}\n")
    with pytest.warns(DeprecationWarning, match=f"join.toml: \\[options\\] the option {old} is now "
                      f"called {new}"):  # fmt: skip
        spec = load_case(folder)
    assert getattr(spec.options, new) == value
    assert new in spec.to_json()["options"] and old not in spec.to_json()["options"]
    spec = load_case(make_case(tmp_path, sample, f"[options]\n{new} = {value}\n", "new"))
    assert getattr(spec.options, new) == value
    both = make_case(tmp_path, sample, f"[options]\n{old} = {value}\n{new} = {value}\n", "both")
    with pytest.raises(igljoin.SpecError, match=f"{old} and {new} are the same option"):
        load_case(both)
