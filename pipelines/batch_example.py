"""Run a folder of case folders through the Python API and look at the results.

Usage::

    python pipelines/batch_example.py CASES OUT [--workers N | --dask-local N] [--resume]

Without CASES on disk, make some first::

    python pipelines/make_phantom_cases.py cases --resolution 0.4
    python pipelines/batch_example.py cases out

It is the Python twin of ``igljoin batch CASES -o OUT``: it calls
:func:`igljoin.pipeline.run_batch`, prints one line per case from the
returned :class:`~igljoin.pipeline.BatchSummary`, and reads one case's
``report.json`` back. Note the ``if __name__ == "__main__":`` guard: worker
processes are started with ``spawn`` and import this file, which must not
start a batch again.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from igljoin.pipeline import run_batch


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("cases", type=Path, help="folder of case folders")
    parser.add_argument("out", type=Path, help="output folder")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, help="local worker processes")
    where.add_argument("--dask-local", type=int, help="start a local dask cluster of N workers")
    parser.add_argument("--resume", action="store_true", help="skip cases already done")
    args = parser.parse_args(argv)

    summary = run_batch(
        args.cases,
        args.out,
        workers=args.workers,
        dask_local=args.dask_local,
        resume=args.resume,
    )
    print(f"{'case':<24} {'status':<7} {'iter':>5} {'crease mean':>12} {'area change':>12}")
    for row in summary.rows:
        if row["status"] == "ok":
            print(
                f"{row['name']:<24} {'ok':<7} {row['iterations']:>5} "
                f"{row['crease_mean']:>11.2f}° {row['area_change_mean']:>11.1%}"
            )
        else:
            print(f"{row['name']:<24} {row['status']:<7} {row['step']}: {row['error_type']}")
    ok = [r["name"] for r in summary.rows if r["status"] == "ok"]
    if ok:
        report = json.loads((args.out / ok[0] / "report.json").read_text(encoding="utf-8"))
        print(f"\n{ok[0]}: inputs {sorted(report['inputs'])}, outputs {sorted(report['outputs'])}")
    print(summary.message())
    return 0 if summary.ok else 1


if __name__ == "__main__":
    sys.exit(main())
