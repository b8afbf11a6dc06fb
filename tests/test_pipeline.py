"""Batches over case folders (igljoin.pipeline), run through the real console script.

The cases are written by ``pipelines/make_phantom_cases.py --resolution 0.4
--include-bad``: the paper's six samples, an open seam, a coarse guest that is
resampled, a guest with a stiffness file, a case whose guest is not a mesh
and a case whose spec names a file outside its folder — 11 cases, 2 failing.
"""

from __future__ import annotations

import csv
import fcntl
import hashlib
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

import igljoin
from igljoin.pipeline import ROW_FIELDS, is_current, run_batch, run_case

ROOT = Path(__file__).resolve().parents[1]
IGLJOIN = Path(sys.executable).parent / "igljoin"
N_CASES, BAD = 11, ["bad-mesh", "bad-outside"]


def igljoin_cli(*args, timeout=300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(IGLJOIN), *map(str, args)], capture_output=True, text=True, timeout=timeout
    )


def file_hashes(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _without_time(path: Path) -> object:
    """summary.csv / summary.json with the documented wall-time field removed."""
    if path.suffix == ".csv":
        rows = list(csv.DictReader(io.StringIO(path.read_text(encoding="utf-8"))))
        return [{k: v for k, v in r.items() if k != "time_seconds"} for r in rows]
    doc = json.loads(path.read_text(encoding="utf-8"))
    doc["rows"] = [{k: v for k, v in r.items() if k != "time_seconds"} for r in doc["rows"]]
    return doc


MANIFEST = ".igljoin-manifest.json"
VARYING = ("timings.json", MANIFEST)  # wall times, and the manifest that holds their hashes


def _manifest_without_times(path: Path) -> dict:
    files = json.loads(path.read_text(encoding="utf-8"))["files"]
    return {k: v for k, v in files.items() if k not in ("timings.json", *SUMMARIES)}


SUMMARIES = ("summary.csv", "summary.json")


def assert_same_outputs(a: Path, b: Path) -> None:
    """Byte-identical outputs except wall times: timings.json, time_seconds, their hashes."""
    fa = {k: v for k, v in file_hashes(a).items() if not k.endswith(VARYING)}
    fb = {k: v for k, v in file_hashes(b).items() if not k.endswith(VARYING)}
    assert sorted(fa) == sorted(fb)
    differing = [k for k in fa if k not in SUMMARIES and fa[k] != fb[k]]
    assert differing == []
    for name in SUMMARIES:
        assert _without_time(a / name) == _without_time(b / name)
    ma = sorted(p.relative_to(a) for p in a.rglob(MANIFEST))
    assert ma == sorted(p.relative_to(b) for p in b.rglob(MANIFEST))
    for rel in ma:
        assert _manifest_without_times(a / rel) == _manifest_without_times(b / rel)


def hidden(root: Path) -> list[Path]:
    """Hidden entries under ``root`` other than igljoin's manifests (temporary files, locks)."""
    return [p for p in root.rglob(".*") if p.name != MANIFEST]


@pytest.fixture(scope="module")
def cases(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("cases")
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "pipelines" / "make_phantom_cases.py"),
            str(root),
            "--resolution",
            "0.4",
            "--include-bad",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    return root


@pytest.fixture(scope="module")
def input_hashes(cases) -> dict:
    """Every input byte, taken before any batch ran."""
    return file_hashes(cases)


@pytest.fixture(scope="module")
def local_run(cases, input_hashes, tmp_path_factory):
    assert IGLJOIN.exists(), "console script missing: run .venv/bin/pip install -e ."
    out = tmp_path_factory.mktemp("out") / "local"
    proc = igljoin_cli("batch", cases, "-o", out, "--workers", "2", "--json")
    return proc, out


# --------------------------------------------------------------------------- a batch


def test_batch_exit_code_counts_the_failures(local_run):
    proc, out = local_run
    assert proc.returncode == 1
    last = proc.stderr.strip().splitlines()[-1]
    # then "; N with warnings: ..." if some cases have quality warnings
    assert last.split(";")[0] == "igljoin: 2 of 11 cases failed: bad-mesh, bad-outside"
    assert "Traceback" not in proc.stderr
    doc = json.loads(proc.stdout)  # --json: nothing else on stdout
    assert doc["cases"] == N_CASES and doc["failed_cases"] == BAD
    assert sorted(doc["ran"]) == doc["ran"] and len(doc["ran"]) == N_CASES
    assert doc["skipped"] == []


def test_summary_rows(local_run, cases):
    _, out = local_run
    rows = list(csv.DictReader(io.StringIO((out / "summary.csv").read_text())))
    assert [r["name"] for r in rows] == sorted(p.name for p in cases.iterdir())
    assert list(rows[0]) == list(ROW_FIELDS)
    by_name = {r["name"]: r for r in rows}
    bad = by_name["bad-mesh"]
    assert (bad["status"], bad["step"], bad["error_type"]) == ("failed", "read", "MeshReadError")
    assert "guest.obj" in bad["error_message"]
    bad = by_name["bad-outside"]
    assert (bad["status"], bad["step"], bad["error_type"]) == ("failed", "spec", "SpecError")
    assert "'../bad-mesh/host.ply'" in bad["error_message"]
    assert "outside the case folder" in bad["error_message"]
    for name, r in by_name.items():
        if name in BAD:
            continue
        assert r["status"] == "ok" and r["converged"] == "True" and r["error_type"] == ""
        assert int(r["iterations"]) > 0 and int(r["seam"]) > 0 and int(r["hard"]) > 0
        # the seam is a hard constraint: only rounding is left (1e-9 of a host edge)
        assert float(r["seam_gap_relative_max"]) < 1e-9
        # measured 0.0 to 0.97 degrees; a crease of a few degrees would be a failed smooth join
        assert float(r["crease_mean"]) < 2.0
        assert float(r["time_seconds"]) > 0
        # the warnings column holds the codes of the report's warnings (docs/warnings.md)
        report = json.loads((out / name / "report.json").read_text())
        assert r["warnings"] == ";".join(w["code"] for w in report["warnings"])
        # none is about the join itself (host_creased reports the inputs' own crease)
        assert set(filter(None, r["warnings"].split(";"))) <= {"host_creased"}
    assert by_name["partial_patch-coarse"]["resampled"] == "True"
    assert by_name["partial_patch-equal"]["resampled"] == "False"
    sample = igljoin.phantoms.paper_sample("end_to_end", "equal", resolution=0.4)
    row = by_name["end_to_end-equal"]
    assert int(row["host_vertices"]) == sample.host.n_vertices
    doc = json.loads((out / "summary.json").read_text())
    assert doc["failed_cases"] == BAD and len(doc["rows"]) == N_CASES
    warned = [r["name"] for r in rows if r["status"] == "ok" and r["warnings"]]
    assert doc["warned"] == len(warned) and doc["warned_cases"] == warned


def test_good_cases_outputs_are_complete(local_run, cases):
    _, out = local_run
    for case in sorted(cases.iterdir()):
        folder = out / case.name
        if case.name in BAD:
            assert sorted(p.name for p in folder.iterdir()) == [
                MANIFEST,
                "error.json",
                "timings.json",
            ]
            error = json.loads((folder / "error.json").read_text())
            assert set(error) == {"case", "igljoin_version", "type", "message", "step", "inputs"}
            continue
        names = sorted(p.name for p in folder.iterdir())
        assert names == [
            MANIFEST,
            "guest.ply",
            "guest.vtu",
            "merged.ply",
            "merged.vtu",
            "report.json",
            "timings.json",
        ]
        report = json.loads((folder / "report.json").read_text())
        assert report["case"] == case.name and report["igljoin_version"] == igljoin.__version__
        for role, entry in report["inputs"].items():
            data = (case / entry["file"]).read_bytes()
            assert entry["sha256"] == hashlib.sha256(data).hexdigest(), role
        assert {"host", "guest", "spec"} <= set(report["inputs"])
        for name, digest in report["outputs"].items():
            assert hashlib.sha256((folder / name).read_bytes()).hexdigest() == digest
        # timings live in timings.json only, so that report.json is reproducible
        assert "timings" not in report and "time_seconds" not in report["metrics"]
        assert json.loads((folder / "timings.json").read_text())["total"] > 0
        defaults = igljoin.JoinOptions().to_json()  # the effective spec lists defaults too
        assert report["spec"]["options"]["max_iterations"] == defaults["max_iterations"]
        guest = igljoin.read_mesh(folder / "guest.ply")
        assert guest.n_vertices == report["counts"]["points"]
        assert "area_ratio" in guest.face_attributes
        assert igljoin.read_mesh(folder / "merged.ply").n_faces > guest.n_faces
    stiff = json.loads((out / "partial_patch-stiff" / "report.json").read_text())
    assert stiff["inputs"]["stiffness"]["file"] == "stiffness.npy"
    coarse = json.loads((out / "partial_patch-coarse" / "report.json").read_text())
    assert coarse["resample"]["boundary_deviation"] < 1e-9  # pinned boundary: rounding only
    assert not hidden(out)  # no temporary files, no lock left


def test_inputs_are_untouched(local_run, cases, input_hashes):
    assert file_hashes(cases) == input_hashes


# --------------------------------------------------------------------------- dask


def test_dask_local_cluster_gives_identical_outputs(local_run, cases, tmp_path):
    pytest.importorskip("distributed")
    _, local = local_run
    out = tmp_path / "dask"
    proc = igljoin_cli("batch", cases, "-o", out, "--dask-local", "2", "--json")
    assert proc.returncode == 1, proc.stderr
    assert json.loads(proc.stdout)["failed_cases"] == BAD
    assert_same_outputs(local, out)


# --------------------------------------------------------------------------- interruption


def test_sigkill_then_resume_equals_an_uninterrupted_run(local_run, cases, input_hashes, tmp_path):
    _, reference = local_run
    out = tmp_path / "killed"
    proc = subprocess.Popen(
        [str(IGLJOIN), "batch", str(cases), "-o", str(out), "--workers", "1", "--no-progress"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # its own process group: the kill takes the worker too
    )
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if out.is_dir() and any((p / "report.json").is_file() for p in out.iterdir()):
                break  # the first successful case is in place
            time.sleep(0.002)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL  # killed mid-run, not finished
    done = sorted(p.name for p in out.iterdir() if p.is_dir() and not p.name.startswith("."))
    assert 1 <= len(done) < N_CASES and not (out / "summary.csv").exists()
    ok_before = {n for n in done if (out / n / "report.json").is_file()}
    resumed = igljoin_cli("batch", cases, "-o", out, "--resume", "--json")
    assert resumed.returncode == 1
    doc = json.loads(resumed.stdout)
    assert set(doc["skipped"]) == ok_before  # finished cases were not run again
    assert set(doc["ran"]) == {p.name for p in cases.iterdir()} - ok_before
    assert_same_outputs(reference, out)
    assert not hidden(out)  # no temporary folders or files left
    assert file_hashes(cases) == input_hashes


def test_resume_reruns_changed_and_failed_cases_only(local_run, cases, tmp_path):
    _, reference = local_run
    work = tmp_path / "cases"
    shutil.copytree(cases, work)
    out = tmp_path / "out"
    shutil.copytree(reference, out)
    summary = run_batch(work, out, resume=True, workers=0, progress=False)
    assert summary.ran == BAD  # failed cases always run again
    assert len(summary.skipped) == N_CASES - len(BAD)
    # change one input and one spec: those two cases run again
    spec = work / "partial_patch-equal" / "join.toml"
    spec.write_text(spec.read_text() + "\n[options]\nsmooth_weight = 5.0\n")
    (work / "end_to_end-equal" / "join.toml").write_bytes(
        (work / "end_to_end-equal" / "join.toml").read_bytes() + b"\n# an edit\n"
    )
    summary = run_batch(work, out, resume=True, workers=0, progress=False)
    assert summary.ran == [*BAD, "end_to_end-equal", "partial_patch-equal"]
    report = json.loads((out / "partial_patch-equal" / "report.json").read_text())
    assert report["spec"]["options"]["smooth_weight"] == 5.0
    # a tampered output is detected as well
    assert is_current(work / "open_strip-equal", out / "open_strip-equal")
    with open(out / "open_strip-equal" / "guest.ply", "ab") as fh:
        fh.write(b"\0")
    assert not is_current(work / "open_strip-equal", out / "open_strip-equal")


def test_run_case_replaces_an_output_whole(cases, tmp_path):
    out = tmp_path / "one"
    row = run_case(cases / "open_strip-equal", out)
    assert row["status"] == "ok"
    first = json.loads((out / "report.json").read_text())
    row = run_case(cases / "bad-mesh", out)  # a failure replaces the whole folder
    assert row["status"] == "failed" and row["step"] == "read"
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "error.json", "timings.json"]
    run_case(cases / "open_strip-equal", out)
    assert json.loads((out / "report.json").read_text()) == first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one"]  # nothing set aside is left
    with pytest.raises(igljoin.MeshReadError):
        run_case(cases / "bad-mesh", out, record_errors=False)
    assert json.loads((out / "report.json").read_text()) == first  # untouched


def test_one_batch_per_output_folder(cases, tmp_path):
    out = tmp_path / "locked"
    out.mkdir()
    with open(out / ".igljoin-batch.lock", "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(OSError, match="another igljoin batch is writing"):
            run_batch(cases, out, workers=0, progress=False)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"workers": -1}, "workers=-1"),
        ({"workers": 2, "dask_local": 2}, "workers applies to local processes only"),
        ({"scheduler": "tcp://x:1", "dask_local": 2}, "scheduler and dask_local"),
        ({"dask_local": 0}, "dask_local=0"),
    ],
)
def test_run_batch_argument_errors(cases, tmp_path, kwargs, match):
    with pytest.raises(igljoin.OptionsError, match=match):
        run_batch(cases / "open_strip-equal", tmp_path / "o", progress=False, **kwargs)


def test_batch_example_script(local_run, cases, tmp_path):
    _, reference = local_run
    out = tmp_path / "example"
    shutil.copytree(reference, out)
    proc = subprocess.run(
        [sys.executable, str(ROOT / "pipelines" / "batch_example.py"), str(cases), str(out)]
        + ["--resume", "--workers", "1"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 1, proc.stderr  # the two bad cases
    assert "2 of 11 cases failed: bad-mesh, bad-outside" in proc.stdout
    assert "partial_patch-coarse" in proc.stdout


def test_any_executor_and_a_scheduler_address(cases, local_run, tmp_path):
    """A dask scheduler reached by its address, and a plain thread pool, run cases too."""
    distributed = pytest.importorskip("distributed")
    _, reference = local_run
    two = tmp_path / "two"
    two.mkdir()
    for name in ("open_strip-equal", "partial_patch-equal"):
        shutil.copytree(cases / name, two / name)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, host="127.0.0.1", dashboard_address=None
    ) as cluster:
        summary = run_batch(
            two, tmp_path / "sched", scheduler=cluster.scheduler_address, progress=False
        )
    assert summary.ok and summary.n_cases == 2
    with ThreadPoolExecutor(2) as pool:
        summary = run_batch(two, tmp_path / "threads", executor=pool, progress=False)
    assert summary.ok
    for out in (tmp_path / "sched", tmp_path / "threads"):
        for name in ("open_strip-equal", "partial_patch-equal"):
            a, b = out / name / "report.json", reference / name / "report.json"
            assert a.read_bytes() == b.read_bytes()


def test_resume_redoes_a_case_missing_a_newly_requested_format(cases, tmp_path):
    work = tmp_path / "cases"
    shutil.copytree(cases / "open_strip-equal", work / "open_strip-equal")
    out = tmp_path / "out"
    first = run_batch(work, out, workers=0, progress=False, formats="ply")
    assert first.ran == ["open_strip-equal"]
    case_out = out / "open_strip-equal"
    assert not (case_out / "guest.vtu").exists()
    assert not is_current(work / "open_strip-equal", case_out, formats="ply,vtu")
    summary = run_batch(work, out, resume=True, workers=0, progress=False, formats="ply,vtu")
    assert summary.ran == ["open_strip-equal"]
    assert (case_out / "guest.vtu").is_file() and (case_out / "merged.vtu").is_file()
    # every requested format present: skipped, also when fewer are asked for
    for formats in ("ply,vtu", "ply", "vtu"):
        summary = run_batch(work, out, resume=True, workers=0, progress=False, formats=formats)
        assert summary.skipped == ["open_strip-equal"], formats
