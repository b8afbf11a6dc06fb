"""The benchmark's records of the machines its tables come from (``pipelines/benchmark.py``).

A run with ``--only`` keeps the other cases of the earlier file and records
the earlier run's machine; files written before kept them nested one inside
another. Here only that they read back as one flat list, newest first.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "pipelines"))
import benchmark  # noqa: E402


def test_nested_earlier_runs_read_as_a_flat_list_newest_first():
    oldest = {"load_average_start": [3.0]}
    middle = {"load_average_start": [2.0], "earlier_runs": oldest}
    newest = {"load_average_start": [1.0], "earlier_runs": middle}
    runs = benchmark._earlier_runs(newest)
    assert [r["load_average_start"] for r in runs] == [[1.0], [2.0], [3.0]]
    assert all("earlier_runs" not in r for r in runs)


def test_a_flat_list_stays_as_it_is():
    flat = [{"load_average_start": [1.0]}, {"load_average_start": [2.0]}]
    assert benchmark._earlier_runs(flat) == flat
    assert benchmark._earlier_runs([]) == []


def test_tables_are_rewritten_from_the_json_keeping_the_hand_written_head(tmp_path):
    docs = Path(__file__).resolve().parent.parent / "docs"
    results = (docs / "benchmarks.json").read_text()
    (tmp_path / "benchmarks.json").write_text(results)
    head = "# Benchmarks\n\nWritten by hand.\n\n"
    (tmp_path / "benchmarks.md").write_text(head + "<!-- benchmark tables -->\n\nold tables\n")
    assert benchmark.main(["--tables", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "benchmarks.md").read_text()
    assert text.startswith(head + "<!-- benchmark tables -->\n\n")
    assert "old tables" not in text
    assert text.endswith(benchmark.markdown(json.loads(results)))


def test_tables_without_a_json_name_the_missing_file(tmp_path):
    with pytest.raises(SystemExit, match="benchmarks.json"):
        benchmark.main(["--tables", "--out", str(tmp_path)])
