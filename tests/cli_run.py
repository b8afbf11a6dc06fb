"""Running the ``igljoin`` command line in a test: in this process, or as a real process.

:func:`call` runs ``igljoin.cli.main(argv)`` here, with stdout and stderr
captured, and returns what a subprocess would: the exit code (argparse's
``SystemExit`` included), stdout and stderr. It saves the interpreter start
and the imports of every run. An exception that escapes ``main`` is what
would have been a traceback: it propagates and fails the test.

:func:`spawn` runs the installed console script as a real process, for what
needs one: the exit status the operating system sees, signals, terminals.
"""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
from pathlib import Path

from igljoin.cli import main

#: The console script installed beside this interpreter.
IGLJOIN = Path(sys.executable).parent / "igljoin"


def call(*args) -> subprocess.CompletedProcess:
    """``igljoin ARGS`` through ``main(argv)`` in this process.

    Parameters
    ----------
    *args : str or path
        The command line without the program name.

    Returns
    -------
    subprocess.CompletedProcess
        ``returncode``, ``stdout`` and ``stderr`` (text) as the console
        script would give them.
    """
    argv = [str(a) for a in args]
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse: --help, --version, usage errors
            code = exc.code
    if code is None:
        code = 0
    elif not isinstance(code, int):  # sys.exit("message") prints it and exits 1
        err.write(f"{code}\n")
        code = 1
    return subprocess.CompletedProcess(["igljoin", *argv], code, out.getvalue(), err.getvalue())


def spawn(*args, timeout: float = 300) -> subprocess.CompletedProcess:
    """``igljoin ARGS`` as a real process (the installed console script)."""
    assert IGLJOIN.exists(), "console script missing: run .venv/bin/pip install -e ."
    return subprocess.run(
        [str(IGLJOIN), *map(str, args)], capture_output=True, text=True, timeout=timeout
    )
