"""The code of the README and the documentation pages that needs no training runs as
written: their Python snippets, in reading order, and the ``--help`` of every command."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys

import pytest

from tests.scripts import REPO

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(1200)]

README = (REPO / "README.md").read_text()
# The pages in the site's reading order (docs/index.md's toctrees).
PAGES = [REPO / "README.md"] + [
    REPO / "docs" / f"{name}.md"
    for name in re.findall(r"^([a-z-]+)$", (REPO / "docs/index.md").read_text(), flags=re.M)
]
DOCS = "\n".join(page.read_text() for page in PAGES)
PYTHON_BLOCKS = re.findall(r"^```python\n(.*?)^```", DOCS, flags=re.S | re.M)
COMMANDS = [
    ["train.py"],
    ["evaluate.py"],
    ["-m", "minitaur_env.sweep"],
    ["-m", "minitaur_env.package"],
    ["-m", "minitaur_env.onnx"],
    ["-m", "minitaur_env.ship"],
]


def without_training(block: str) -> str:
    """The block without the statements that train (those that call ``.run()``) and those
    that use what they return."""
    kept, dropped_names = [], set()
    for node in ast.parse(block).body:
        source = ast.get_source_segment(block, node) or ""
        used = {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}
        if ".run()" in source or used & dropped_names:
            dropped_names |= {
                target.id
                for target in ast.walk(node)
                if isinstance(target, ast.Name) and isinstance(target.ctx, ast.Store)
            }
            continue
        kept.append(source)
    return "\n".join(kept)


def test_the_docs_have_the_snippets_this_test_runs():
    assert len(PAGES) >= 10 and all(page.is_file() for page in PAGES)
    assert len(PYTHON_BLOCKS) >= 4
    assert any("gym.make" in block for block in re.findall(r"```python\n(.*?)```", README, re.S))


def test_python_snippets_run(tmp_path):
    # In order, in one namespace: the ONNX snippet plays the obs of the first one, and
    # runs where a policy.onnx lies (the shipped PPO's, copied: it sees one observation,
    # as the first snippet's env gives it).
    shutil.copyfile(
        REPO / "pretrained/ppo/MinitaurBulletEnv-v0_1/policy.onnx", tmp_path / "policy.onnx"
    )
    script = "\n\n".join(without_training(block) for block in PYTHON_BLOCKS)
    script += "\nprint(frame.shape, action.shape, config.seed)"
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split("\n")[-2] == "(480, 640, 3) (8,) 1"


def test_without_training_drops_only_the_training_calls():
    block = "x = 1\nresult = Experiment.create(c).run()\nprint(result)\nprint(x)\n"
    assert without_training(block) == "x = 1\nprint(x)"


@pytest.mark.parametrize("command", COMMANDS, ids=" ".join)
def test_every_command_has_help(command):
    shown = subprocess.run(
        [sys.executable, *command, "--help"], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert shown.returncode == 0, shown.stderr
    assert shown.stdout.startswith("usage:")
    name = command[-1].removeprefix("minitaur_env.")
    assert name in DOCS, f"neither the README nor the docs name {name}"
