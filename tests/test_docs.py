"""The documentation and the release: the site builds with warnings as errors (and a broken
reference does fail it), both tutorial notebooks run, the README stays a short entry page
whose links resolve, and the built wheel, installed into a fresh virtual environment,
registers the env, carries its hyperparameter files and runs ``minitaur train``,
``evaluate`` and ``onnx`` away from the checkout."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from minitaur_env.training.evaluation import NO_MODEL_HINT
from tests.scripts import REPO, error_lines, needs

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]

DOCS = REPO / "docs"
NOTEBOOKS = sorted((DOCS / "tutorials").glob("*.ipynb"))


def sphinx(source: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "sphinx",
            "-E",
            "-W",
            "--keep-going",
            "-q",
            "-b",
            "html",
            str(source),
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=900,
    )


def test_the_site_builds_with_warnings_as_errors(tmp_path):
    needs("sphinx"), needs("myst_nb"), needs("furo")
    built = sphinx(DOCS, tmp_path / "html")
    assert built.returncode == 0, built.stderr[-3000:]
    api = (tmp_path / "html" / "api.html").read_text()
    for name in (
        "minitaur_env.MinitaurBulletEnv",
        "minitaur_env.Realism",
        "minitaur_env.DynamicsRanges",
        "minitaur_env.training.config.ExperimentConfig",
        "minitaur_env.training.experiment.Experiment",
        "minitaur_env.training.run_folder.RunFolder",
        "minitaur_env.onnx_policy.OnnxPolicy",
    ):
        assert f'id="{name}"' in api, f"{name} is missing from the API reference"
    for page in (
        "environment",
        "training",
        "results",
        "tutorials/sac_minitaur",
        "tutorials/ppo_cartpole",
        "changelog",
    ):
        assert (tmp_path / "html" / f"{page}.html").is_file(), page


def test_a_broken_reference_fails_the_build(tmp_path):
    # The negative control for the test above: the same conf.py, one bad page.
    needs("sphinx"), needs("myst_nb")
    source = tmp_path / "docs"
    source.mkdir()
    shutil.copy(DOCS / "conf.py", source)
    (source / "index.md").write_text(
        "# Broken\n\n{py:class}`minitaur_env.NoSuchEnv`, and [a page](missing-page.md).\n"
    )
    built = sphinx(source, tmp_path / "html")
    assert built.returncode != 0
    assert "minitaur_env.NoSuchEnv" in built.stderr and "missing-page" in built.stderr


@pytest.mark.parametrize("notebook", NOTEBOOKS, ids=lambda path: path.stem)
def test_tutorial_notebook_runs_on_a_tiny_budget(notebook, tmp_path, monkeypatch):
    nbformat, nbclient = needs("nbformat"), needs("nbclient")
    needs("ipykernel")
    document = nbformat.read(notebook, as_version=4)
    assert all(not cell.get("outputs") for cell in document.cells if cell.cell_type == "code"), (
        "commit notebooks without outputs: the site shows the code, the suite runs it"
    )
    # SAC's tiny budget is half of PPO's: its 8 updates per 8 steps dominate the test.
    monkeypatch.setenv("TUTORIAL_STEPS", "512" if notebook.stem == "sac_minitaur" else "1024")
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    client = nbclient.NotebookClient(
        document, timeout=600, kernel_name="python3", resources={"metadata": {"path": tmp_path}}
    )
    client.execute()  # raises CellExecutionError, naming the cell, on any error
    text = "\n".join(
        output.get("text", "")
        for cell in document.cells
        if cell.cell_type == "code"
        for output in cell.outputs
    )
    assert "completed after" in text  # the training cell ran to its budget
    assert re.search(r"^return\s+-?[0-9.]+", text, re.M)  # the evaluation table
    videos = list((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000
    runs = list((tmp_path / "logs" / "tutorial").glob("*/*/evaluations.npz"))
    assert len(runs) == 1


def markdown_links(text: str) -> list[str]:
    return re.findall(r"\]\(([^)\s]+)\)", text)


def slug(heading: str) -> str:
    """GitHub's (and MyST's) anchor for a heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def test_the_readme_is_a_short_entry_page_whose_links_resolve():
    readme = (REPO / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    local = [link for link in markdown_links(readme) if not link.startswith("http")]
    assert len(local) >= 10  # it points into the site
    for link in local:
        path, _, anchor = link.partition("#")
        target = REPO / path
        assert target.exists(), f"README links to {path}, which does not exist"
        if anchor:
            headings = re.findall(r"^#+ (.*)$", target.read_text(), re.M)
            assert anchor in {slug(h) for h in headings}, f"{link}: no such heading"


def test_slug_matches_githubs_anchors():
    assert slug("Stabilizing SAC: the ablation so far (work in progress)") == (
        "stabilizing-sac-the-ablation-so-far-work-in-progress"
    )
    assert slug("Training: `train.py`") == "training-trainpy"


def test_the_wheel_installs_into_a_fresh_environment_and_its_minitaur_command_works_there(
    tmp_path,
):
    needs("build"), needs("twine")
    # Build from a copy: building in place would leave build/ and egg-info in the checkout.
    source = tmp_path / "source"
    shutil.copytree(
        REPO,
        source,
        ignore=shutil.ignore_patterns(
            ".git",
            ".venv",
            "logs",
            "sweeps",
            "benchmarks",
            "pretrained",
            "videos",
            "tests",
            "docs",
            "build",
            "dist",
            "*.egg-info",
            "__pycache__",
            ".*_cache",
        ),
    )
    dist = tmp_path / "dist"
    built = subprocess.run(
        [sys.executable, "-m", "build", "--no-isolation", "--outdir", str(dist), str(source)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert built.returncode == 0, built.stderr[-2000:]
    files = sorted(p.name for p in dist.iterdir())
    import minitaur_env

    version = minitaur_env.__version__
    assert files == [f"minitaur_env-{version}-py3-none-any.whl", f"minitaur_env-{version}.tar.gz"]
    checked = subprocess.run(
        [sys.executable, "-m", "twine", "check", "--strict", *map(str, dist.iterdir())],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert checked.returncode == 0, checked.stdout + checked.stderr

    # A fresh environment that sees this one's dependencies (gymnasium, pybullet, SB3) but
    # not its editable checkout: a .pth line adds a directory without running its .pth files.
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    fresh_site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    Path(fresh_site, "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    wheel = next(dist.glob("*.whl"))
    installed = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(python),
            "install",
            "--no-deps",
            "--no-index",
            "-q",
            str(wheel),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert installed.returncode == 0, installed.stderr
    probe = (
        "import gymnasium as gym, minitaur_env\n"
        "from minitaur_env.training.hyperparams import load_hyperparams\n"
        "from pathlib import Path\n"
        "print(minitaur_env.__file__)\n"
        "print(minitaur_env.__version__)\n"
        "folder = Path(minitaur_env.__file__).parent / 'hyperparams'\n"
        "print(sorted(p.name for p in folder.glob('*.yml')))\n"
        "print(load_hyperparams('sac', 'MinitaurBulletEnv-v0')['n_timesteps'])\n"
        "env = gym.make('MinitaurBulletEnv-v0'); print(env.reset(seed=0)[0].shape)\n"
    )
    clean = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    ran = subprocess.run(
        [str(python), "-c", probe],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env=clean,
    )
    assert ran.returncode == 0, ran.stderr[-2000:]
    where, shown_version, ymls, n_timesteps, shape = ran.stdout.strip().splitlines()[-5:]
    assert where.startswith(fresh_site)  # the wheel's copy, not the checkout
    assert shown_version == version
    shipped = sorted(p.name for p in (REPO / "minitaur_env" / "hyperparams").glob("*.yml"))
    assert ymls == str(shipped) and len(shipped) >= 5
    assert int(n_timesteps) > 0 and shape == "(28,)"

    # The console script, away from the checkout: train, evaluate with a video, export.
    minitaur = str(venv / "bin" / "minitaur")
    work = tmp_path / "elsewhere"
    work.mkdir()

    def minitaur_run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [minitaur, *args], cwd=work, capture_output=True, text=True, timeout=900, env=clean
        )

    # With no model and no repository around, one line says how to get a shipped policy.
    nothing = minitaur_run("evaluate")
    assert nothing.returncode == 2
    assert error_lines(nothing) == [f"minitaur evaluate: error: {NO_MODEL_HINT}"]
    trained = minitaur_run("train", "-n", "2000", "--eval-freq", "0", "--progress", "none")
    assert trained.returncode == 0, trained.stderr[-2000:]
    run = work / "logs" / "sac" / "MinitaurBulletEnv-v0_1"
    model = run / "MinitaurBulletEnv-v0.zip"
    assert model.is_file()
    assert (run / "command.txt").read_text().startswith("minitaur train -n 2000")
    shown = minitaur_run(
        "evaluate",
        "--model",
        str(model),
        "--episodes",
        "1",
        "--render-video",
        "--video-episodes",
        "1",
        "--width",
        "96",
        "--height",
        "72",
        "--env-kwargs",
        "max_episode_steps=50",
    )
    assert shown.returncode == 0, shown.stderr[-2000:]
    (video,) = (work / "videos").glob("*.mp4")
    assert video.stat().st_size > 1000
    exported = minitaur_run("onnx", str(run), "-o", "policy.onnx")
    assert exported.returncode == 0, exported.stderr[-2000:]
    assert (work / "policy.onnx").stat().st_size > 1000


def test_the_layout_page_names_every_module():
    layout = (DOCS / "development.md").read_text()
    modules = sorted({path.name for path in (REPO / "minitaur_env").rglob("*.py")})
    missing = [name for name in modules if name not in layout]
    assert not missing, f"docs/development.md's layout does not name {missing}"
