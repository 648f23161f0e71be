from __future__ import annotations

import getpass
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
REFERENCE = Path(__file__).parent / "data" / "minitaur_v0_reference.npz"

# Scratch shared by the suite's processes, which inherit these variables: SBX compiles
# each algorithm's JAX update anew in every process (10-20 s), so they share one
# compilation cache; SB3's learn() without a logger folder makes an empty
# /tmp/SB3-<timestamp> per model, so they share one folder instead of a hundred.
SCRATCH = Path(tempfile.gettempdir()) / f"minitaur-env-tests-{getpass.getuser()}"
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(SCRATCH / "jax-cache"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
os.environ.setdefault("SB3_LOGDIR", str(SCRATCH / "sb3-logs"))


@pytest.fixture(scope="session")
def reference() -> dict[str, np.ndarray]:
    with np.load(REFERENCE) as data:
        return {key: data[key] for key in data.files}


@pytest.fixture(scope="session")
def display():
    """A DISPLAY for the PyBullet GUI: the existing one, or an Xvfb started for the tests."""
    if os.environ.get("DISPLAY"):
        yield os.environ["DISPLAY"]
        return
    if shutil.which("Xvfb") is None:
        pytest.skip("no DISPLAY and no Xvfb to start one (apt-get install xvfb)")
    # Xvfb picks a free display and writes its number once it accepts clients, so parallel
    # test workers never race for one and nothing waits on the clock.
    read_end, write_end = os.pipe()
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write_end), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        pass_fds=(write_end,),
    )
    os.close(write_end)
    with os.fdopen(read_end) as announced:
        number = announced.readline().strip()
    if not number:
        server.kill()
        pytest.skip("Xvfb exited before it announced a display")
    os.environ["DISPLAY"] = f":{number}"
    try:
        yield os.environ["DISPLAY"]
    finally:
        del os.environ["DISPLAY"]
        server.terminate()
        server.wait(timeout=10)
