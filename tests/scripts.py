"""Helpers to run the repository's scripts in a subprocess, as a user would."""

from __future__ import annotations

import contextlib
import importlib
import io
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[1]

# Small budgets keep every script test at a few seconds: short episodes, tiny evals.
TINY = ["--env-kwargs", "max_episode_steps=40", "-v", "0"]


def run_script(
    script: str, *args: str, cwd: Path, timeout: float = 300, keep_display: bool = False
) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    if not keep_display:
        env.pop("DISPLAY", None)
    return subprocess.run(
        # "-m", "package.module": as a user runs a module; else a script of the repository
        [sys.executable, *(["-m"] if script == "-m" else [str(REPO / script)]), *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )


def run_main(
    main: Callable[[list[str]], int], *args: str, cwd: Path
) -> subprocess.CompletedProcess[str]:
    """A script's ``main(argv)`` in this process, with its exit code, stdout and stderr as
    ``run_script`` gives them: for the many small cases of one script (its user errors),
    without the seconds each new interpreter spends importing torch. An exception that
    escapes ``main`` fails the test, as a traceback would fail a one-line check."""
    stdout, stderr = io.StringIO(), io.StringIO()
    previous = Path.cwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            try:
                code = main(list(args))
            except SystemExit as exit:  # argparse's errors
                code = exit.code if isinstance(exit.code, int) else 1
    finally:
        os.chdir(previous)
    return subprocess.CompletedProcess(["main", *args], code, stdout.getvalue(), stderr.getvalue())


def start_script(
    script: str,
    *args: str,
    cwd: Path,
    own_process_group: bool = False,
    sigint_ignored: bool = False,
) -> subprocess.Popen[str]:
    """Start a script; ``own_process_group`` lets a test signal it and its workers at
    once, as a terminal's Ctrl-C does. The script starts with SIGINT at its default, or
    ignored (``sigint_ignored``) as a non-interactive shell starts a background job,
    whatever the test runner itself inherited."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    disposition = signal.SIG_IGN if sigint_ignored else signal.SIG_DFL
    return subprocess.Popen(
        # "-m", "package.module": as a user runs a module; else a script of the repository
        [sys.executable, *(["-m"] if script == "-m" else [str(REPO / script)]), *args],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=own_process_group,
        preexec_fn=lambda: signal.signal(signal.SIGINT, disposition),
    )


def error_lines(result: subprocess.CompletedProcess[str] | str) -> list[str]:
    """stderr (of a finished script, or as text) without PyBullet's import banner."""
    stderr = result if isinstance(result, str) else result.stderr
    return [
        line
        for line in stderr.splitlines()
        if line.strip() and not line.startswith("pybullet build time")
    ]


def needs(module: str) -> Any:
    """``module``, imported; outside CI a missing one skips the test. CI installs every
    extra (.ci/run), so there a missing module fails the test instead of hiding it."""
    if os.environ.get("CI"):
        return importlib.import_module(module)
    return pytest.importorskip(module)
