"""Batches that are killed, lose a worker, are tampered with or fill the disk (real processes)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import igljoin
from igljoin import phantoms
from igljoin.pipeline import SolvedCase, _Step, _write_outputs, run_batch

from .test_pipeline import assert_same_outputs, file_hashes, hidden
from .tmpfs import small_tmpfs

IGLJOIN = Path(sys.executable).parent / "igljoin"
SLOW = 4  # cases of ~0.5 s each (1,500 iterations, capped): a kill lands while workers are busy


def _write_case(root: Path, name: str, mesh_pair, toml: str) -> None:
    (root / name).mkdir(parents=True)
    igljoin.write_mesh(root / name / "host.ply", mesh_pair[0])
    igljoin.write_mesh(root / name / "guest.ply", mesh_pair[1])
    (root / name / "join.toml").write_text(toml)


@pytest.fixture(scope="module")
def patch():
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.4)
    return s.host, s.guest


@pytest.fixture(scope="module")
def slow_cases(tmp_path_factory, patch) -> Path:
    root = tmp_path_factory.mktemp("slow")
    toml = "[host_curve]\nloop = 0\n[options]\nenergy_tolerance = 1e-300\nmax_iterations = {}\n"
    for k in range(SLOW):
        _write_case(root, f"case{k}", patch, toml.format(1500 + k))  # each case its own result
    return root


@pytest.fixture(scope="module")
def slow_reference(slow_cases, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ref") / "out"
    summary = run_batch(slow_cases, out, workers=0, progress=False)
    assert summary.ok, summary.rows
    return out


def _processes() -> list[tuple[int, list[str], str]]:
    """(pid, stat fields after the command name, command line) of every live process (/proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        found.append((int(entry.name), stat.rsplit(")", 1)[1].split(), cmd))
    return found


def _session_processes(sid: int) -> list[tuple[int, str]]:
    """(pid, command) of every live process of session ``sid``."""
    return [(pid, cmd) for pid, f, cmd in _processes() if int(f[3]) == sid and f[0] != "Z"]


def _children(parent: int) -> list[tuple[int, str]]:
    """(pid, command) of every child of ``parent``."""
    return [(pid, cmd) for pid, f, cmd in _processes() if int(f[1]) == parent]


def _wait_for(predicate, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return False


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
def test_sigkill_of_the_batch_parent_leaves_no_process_and_resume_is_exact(
    slow_cases, slow_reference, tmp_path
):
    out = tmp_path / "killed"
    proc = subprocess.Popen(
        [str(IGLJOIN), "batch", str(slow_cases), "-o", str(out), "--workers", "2"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # its own session: every process it starts is findable
    )
    try:
        started = _wait_for(
            lambda: out.is_dir() and any(p.name.startswith(".case") for p in out.iterdir()),
            120,
        )
        assert started and proc.poll() is None
        time.sleep(0.3)  # both workers are inside a case now
        assert len(_session_processes(proc.pid)) >= 3  # the batch, two workers (+ tracker)
        os.kill(proc.pid, signal.SIGKILL)  # the parent only: its workers must follow by themselves
        proc.wait(timeout=10)
        time.sleep(2.0)  # the bound: nothing of the batch alive 2 s later
        assert _session_processes(proc.pid) == []
    finally:
        for pid, _ in _session_processes(proc.pid):
            os.kill(pid, signal.SIGKILL)
    assert not (out / "summary.csv").exists()
    resumed = subprocess.run(
        [str(IGLJOIN), "batch", str(slow_cases), "-o", str(out), "--resume", "--workers", "2"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert resumed.returncode == 0, resumed.stderr
    assert_same_outputs(slow_reference, out)
    assert not hidden(out)


def test_a_killed_local_worker_does_not_fail_the_queued_cases(slow_cases, slow_reference, tmp_path):
    out = tmp_path / "out"
    result = {}
    thread = threading.Thread(
        target=lambda: result.update(summary=run_batch(slow_cases, out, workers=2, progress=False))
    )
    thread.start()
    try:
        assert _wait_for(
            lambda: out.is_dir() and any(p.name.startswith(".case") for p in out.iterdir()), 120
        )
        workers = [pid for pid, cmd in _children(os.getpid()) if "spawn_main" in cmd]
        assert workers
        os.kill(workers[0], signal.SIGKILL)  # a worker dies mid-case (as the OOM killer does)
    finally:
        thread.join(timeout=300)
    summary = result["summary"]
    assert summary.ok, [r for r in summary.rows if r["status"] != "ok"]
    assert sorted(summary.ran) == [f"case{k}" for k in range(SLOW)]
    assert_same_outputs(slow_reference, out)
    assert not hidden(out)  # the dead worker's staging folder is gone


@pytest.fixture(scope="module")
def fast_cases(tmp_path_factory) -> Path:
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.3)
    root = tmp_path_factory.mktemp("fast")
    for name in ("a", "b"):
        _write_case(root, name, (s.host, s.guest), "[host_curve]\nloop = 0\n")
    return root


def test_resume_redoes_a_tampered_report_and_a_deleted_output(fast_cases, tmp_path):
    out = tmp_path / "out"
    assert run_batch(fast_cases, out, workers=0, progress=False).ok
    reference = file_hashes(out)
    crease = json.loads((out / "summary.json").read_text())["rows"][0]["crease_max"]
    report = out / "a" / "report.json"
    doc = json.loads(report.read_text())
    doc["metrics"]["crease_deg"]["max"] = 0.0  # a fake figure
    report.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    doc = json.loads((out / "b" / "report.json").read_text())
    del doc["outputs"]["merged.ply"]  # hide the output, then delete it
    (out / "b" / "report.json").write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    (out / "b" / "merged.ply").unlink()
    summary = run_batch(fast_cases, out, workers=0, progress=False, resume=True)
    assert summary.ran == ["a", "b"] and summary.skipped == []
    assert summary.rows[0]["crease_max"] == crease
    after = file_hashes(out)
    same = [k for k in reference if not k.endswith(("timings.json", ".json", ".csv"))]
    assert {k: after[k] for k in same} == {k: reference[k] for k in same}
    assert (out / "b" / "merged.ply").is_file()
    summary = run_batch(fast_cases, out, workers=0, progress=False, resume=True)
    assert summary.skipped == ["a", "b"]  # now whole again: nothing to redo


def test_a_failed_save_fails_the_case(tmp_path):
    s = phantoms.paper_sample("end_to_end", "equal", resolution=0.5)
    solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    res = solver.solve()
    moved = solver.solve(targets=res.seam_targets + [0.0, 0.0, 0.5])  # the weld cannot close
    host = igljoin.write_mesh(tmp_path / "h.ply", s.host)
    guest = igljoin.write_mesh(tmp_path / "g.ply", s.guest)
    spec = igljoin.spec.CaseSpec.make(host, guest, None, None, {})
    (tmp_path / "out").mkdir()
    solved = SolvedCase(spec=spec, result=moved, meshes={})
    step = _Step()
    with pytest.raises(igljoin.WeldError, match="off the host curve"):
        _write_outputs(solved, {}, tmp_path / "out", False, step)
    assert step.name == "save"  # recorded as a failure at step "save", never as "ok"


@pytest.fixture
def full_disk():
    """A 192 KiB tmpfs: writes beyond that fail with ENOSPC like a full disk."""
    with small_tmpfs(192) as mnt:
        yield mnt


def test_full_disk_mid_batch_records_every_case_or_names_it(full_disk, tmp_path):
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.3)
    cases = tmp_path / "cases"
    for k in range(16):  # ~20 KiB of outputs per case: the disk fills about half way
        _write_case(cases, f"c{k:02d}", (s.host, s.guest), "[host_curve]\nloop = 0\n")
    out = full_disk / "out"
    summary = run_batch(cases, out, workers=0, progress=False)
    rows = {r["name"]: r for r in summary.rows}
    assert sorted(rows) == [f"c{k:02d}" for k in range(16)]
    ok = [n for n, r in rows.items() if r["status"] == "ok"]
    assert 0 < len(ok) < 16  # the disk really filled mid-batch
    for name, row in rows.items():
        folder = out / name
        if row["status"] == "ok":
            for f in ("guest.ply", "merged.ply"):
                igljoin.read_mesh(folder / f)  # complete files only
        elif name not in summary.unrecorded:
            err = json.loads((folder / "error.json").read_text())
            assert "disk is full" in err["message"] or "No space" in err["message"]
        else:
            assert "disk is full" in row["error_message"] or "No space" in row["error_message"]
    assert not [p for p in out.rglob("*") if ".tmp-" in p.name]  # no partial file anywhere
    if summary.summary_error is None:
        doc = json.loads((out / "summary.json").read_text())
        assert doc["cases"] == 16
    else:
        assert "disk is full" in summary.summary_error


def test_a_worker_without_its_batch_lock_publishes_nothing(fast_cases, tmp_path):
    from igljoin.errors import OutputError
    from igljoin.pipeline import _lock_guard, run_case

    lock = tmp_path / ".igljoin-batch.lock"
    lock.write_text("token-of-the-batch-that-now-owns-the-folder\n")
    guard = _lock_guard(str(lock), "token-of-a-killed-batch")
    with pytest.raises(OutputError, match="no longer holds"):
        run_case(fast_cases / "a", tmp_path / "a", publish_guard=guard)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".igljoin-batch.lock"]  # nothing
    own = _lock_guard(str(lock), "token-of-the-batch-that-now-owns-the-folder")
    assert run_case(fast_cases / "a", tmp_path / "a", publish_guard=own)["status"] == "ok"


def test_a_case_whose_worker_always_dies_fails_alone_with_the_reason(slow_cases, tmp_path):
    """A case that kills its worker each time (as an out-of-memory case does) fails, named."""
    cases = tmp_path / "cases"
    shutil.copytree(slow_cases / "case0", cases / "doomed")
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.3)
    for name in ("a", "b"):
        _write_case(cases, name, (s.host, s.guest), "[host_curve]\nloop = 0\n")
    out = tmp_path / "out"
    stop = threading.Event()

    def killer() -> None:  # whenever "doomed" runs, its worker dies
        while not stop.is_set():
            if out.is_dir() and any(p.name.startswith(".doomed.tmp-") for p in out.iterdir()):
                for pid, cmd in _children(os.getpid()):
                    if "spawn_main" in cmd:
                        os.kill(pid, signal.SIGKILL)
            time.sleep(0.005)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    try:
        summary = run_batch(cases, out, workers=2, progress=False)
    finally:
        stop.set()
        thread.join(timeout=10)
    rows = {r["name"]: r for r in summary.rows}
    assert rows["a"]["status"] == "ok" and rows["b"]["status"] == "ok"
    assert rows["doomed"]["status"] == "failed" and rows["doomed"]["step"] == "worker"
    assert "worker running this case died" in rows["doomed"]["error_message"]
    assert json.loads((out / "doomed" / "error.json").read_text())["step"] == "worker"
    assert not hidden(out)
