"""evaluate.py end to end on a model trained for a few hundred steps: as a user runs it (a
subprocess) where the process matters, else through its main() in this process."""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml
from stable_baselines3 import PPO

import evaluate
from minitaur_env.package import main as package_main
from minitaur_env.training.video import read_video
from tests.scripts import REPO, TINY, error_lines, needs, run_main, run_script

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

SHORT = ["--env-kwargs", "max_episode_steps=30"]


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    root = tmp_path_factory.mktemp("evaluate")
    result = run_script(
        "train.py",
        "-n",
        "200",
        "--hyperparams",
        "learning_starts=50",
        "batch_size=32",
        "--eval-freq",
        "100",
        "--eval-episodes",
        "1",
        "--save-freq",
        "100",
        *TINY,
        cwd=root,
    )
    assert result.returncode == 0, result.stderr
    return root


@pytest.fixture(scope="module")
def best_model(workdir):
    return workdir / "logs" / "sac" / "MinitaurBulletEnv-v0_1" / "best_model.zip"


def test_statistics_table_and_json(workdir, best_model):
    result = run_script(
        "evaluate.py",
        "--model",
        str(best_model),
        "--episodes",
        "3",
        "--json",
        "out/stats.json",
        *SHORT,
        cwd=workdir,
    )
    assert result.returncode == 0, result.stderr
    for label in ("return", "episode length", "forward distance (m)", "speed (m/s)", "falls"):
        assert label in result.stdout
    stats = json.loads((workdir / "out" / "stats.json").read_text())
    assert stats["algo"] == "sac" and stats["episodes"] == 3 and stats["deterministic"]
    summary = stats["summary"]
    episodes = stats["per_episode"]
    assert len(episodes) == 3
    for episode in episodes:
        assert episode["length"] == 30 or episode["fell"] == 1.0
        terms = sum(episode[k] for k in ("reward_forward", "reward_energy"))
        terms += episode["reward_drift"] + episode["reward_shake"]
        assert episode["return"] == pytest.approx(terms, abs=1e-9)
        assert episode["speed"] == pytest.approx(episode["distance"] / (episode["length"] * 0.01))
        assert abs(episode["distance"]) < 1.0  # 0.3 s of a barely trained policy
    returns = [e["return"] for e in episodes]
    assert summary["return"]["mean"] == pytest.approx(np.mean(returns))
    assert summary["return"]["std"] == pytest.approx(np.std(returns))
    assert f"{summary['return']['mean']:.3f}" in result.stdout


def test_same_seed_same_statistics_and_stochastic_mode(workdir, best_model):
    args = ["--model", str(best_model), "--episodes", "2", *SHORT]
    first = run_main(evaluate.main, *args, "--json", "a.json", cwd=workdir)
    second = run_main(evaluate.main, *args, "--json", "b.json", cwd=workdir)
    stochastic = run_main(evaluate.main, *args, "--stochastic", "--json", "c.json", cwd=workdir)
    a, b, c = (json.loads((workdir / f"{n}.json").read_text()) for n in "abc")
    assert first.returncode == second.returncode == stochastic.returncode == 0
    assert a["per_episode"] == b["per_episode"]
    assert not c["deterministic"] and c["per_episode"] != a["per_episode"]


@pytest.mark.parametrize(
    ("selection", "expected"),
    [
        (["--load-best"], "best_model.zip"),
        (["--load-last-checkpoint"], "rl_model_200_steps.zip"),
        (["--load-checkpoint", "100"], "rl_model_100_steps.zip"),
        ([], "MinitaurBulletEnv-v0.zip"),
    ],
)
def test_zoo_style_model_selection(workdir, selection, expected):
    result = run_main(
        evaluate.main,
        "-f",
        "logs",
        "--algo",
        "sac",
        "--env",
        "MinitaurBulletEnv-v0",
        *selection,
        "--episodes",
        "1",
        *SHORT,
        cwd=workdir,
    )
    assert result.returncode == 0, result.stderr
    assert f"{expected} (sac, observations normalized)" in result.stdout.splitlines()[0]


@pytest.mark.parametrize("load_best", [False, True])
def test_the_zoo_plays_our_run_folders(workdir, load_best):
    needs("rl_zoo3")
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "rl_zoo3.enjoy",
            "-f",
            "logs",
            "--algo",
            "sac",
            "--env",
            "MinitaurBulletEnv-v0",
            "--gym-packages",
            "minitaur_env",
            "--no-render",
            "-n",
            "80",
            *(["--load-best"] if load_best else []),
        ],
        cwd=workdir,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    model = "best_model.zip" if load_best else "MinitaurBulletEnv-v0.zip"
    assert f"Loading logs/sac/MinitaurBulletEnv-v0_1/{model}" in result.stdout
    assert "Loading running average" in result.stdout  # <env>/vecnormalize.pkl was found
    # The run's env_kwargs (<env>/args.yml) reached the zoo: 40-step episodes.
    assert result.stdout.count("Episode Length 40") == 2


def test_the_zoos_record_video_runs_through_minitaur_env_zoo(workdir):
    needs("rl_zoo3")
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "minitaur_env.zoo",
            "record_video",
            "-f",
            "logs",
            "--algo",
            "sac",
            "--env",
            "MinitaurBulletEnv-v0",
            "-n",
            "20",
            "-o",
            "zoo-videos",
        ],
        cwd=workdir,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    (video,) = (workdir / "zoo-videos").glob("*.mp4")
    frames, _ = read_video(video)
    assert len(frames) >= 20 and frames.std() > 10
    unknown = subprocess.run(
        [sys.executable, "-m", "minitaur_env.zoo", "no_such_script"], capture_output=True, text=True
    )
    assert error_lines(unknown.stderr) == [
        "python -m minitaur_env.zoo: error: rl_zoo3 has no script 'no_such_script'"
    ]


def test_a_hub_folder_holds_the_zoo_layout_and_a_card_the_hub_parses(workdir, best_model):
    hub = needs("huggingface_hub")
    result = run_main(
        package_main,
        str(best_model.parent),
        "-o",
        "hub",
        "--episodes",
        "2",
        "--video-steps",
        "20",
        cwd=workdir,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    folder = workdir / "hub" / "sac-MinitaurBulletEnv-v0"
    assert sorted(p.name for p in folder.iterdir()) == [
        "README.md",
        "config.yml",
        "env_kwargs.yml",
        "policy.onnx",
        "replay.mp4",
        "results.json",
        "sac-MinitaurBulletEnv-v0.zip",
        "vec_normalize.json",
        "vec_normalize.pkl",
    ]
    final_model = best_model.parent / "MinitaurBulletEnv-v0.zip"  # a run folder's model
    assert (folder / "sac-MinitaurBulletEnv-v0.zip").read_bytes() == final_model.read_bytes()
    results = json.loads((folder / "results.json").read_text())
    assert results["n_eval_episodes"] == 2 and results["is_deterministic"] is True
    card = hub.ModelCard.load(folder / "README.md").data.to_dict()
    assert card["library_name"] == "stable-baselines3"
    assert "MinitaurBulletEnv-v0" in card["tags"] and "reinforcement-learning" in card["tags"]
    (index,) = card["model-index"]
    metric = index["results"][0]["metrics"][0]
    assert metric["type"] == "mean_reward" and metric["value"] == (
        f"{results['mean_reward']:.2f} +/- {results['std_reward']:.2f}"
    )
    assert index["results"][0]["dataset"]["name"] == "MinitaurBulletEnv-v0"
    assert "sac-MinitaurBulletEnv-v0.zip" in (folder / "README.md").read_text()  # usage code
    assert yaml.safe_load((folder / "config.yml").read_text())["normalize"] is True
    frames, _ = read_video(folder / "replay.mp4")
    assert len(frames) == 5 and frames.std() > 10  # 20 steps at 100 Hz, 25 fps: every 4th
    # The packaged zip plays with its statistics, found under the Hub's file name.
    played = run_main(
        evaluate.main,
        "--model",
        str(folder / "sac-MinitaurBulletEnv-v0.zip"),
        "--episodes",
        "1",
        *SHORT,
        cwd=workdir,
    )
    assert played.returncode == 0 and "observations normalized" in played.stdout
    missing = run_main(package_main, "no/such/run", cwd=workdir)
    assert error_lines(missing.stderr) == [
        "python -m minitaur_env.package: error: model file not found: no/such/run"
    ]
    # Packaging again over the folder is refused unless asked for, before any episode.
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    again = (str(best_model.parent), "-o", "hub", "--episodes", "1", "--video-steps", "8")
    refused = run_main(package_main, *again, cwd=workdir)
    assert refused.returncode == 2
    assert error_lines(refused.stderr) == [
        f"python -m minitaur_env.package: error: -o: {Path('hub') / folder.name} is already "
        "there; add --replace to replace it"
    ]
    assert {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()} == before
    replaced = run_main(package_main, *again, "--replace", cwd=workdir)  # control
    assert replaced.returncode == 0, replaced.stderr[-2000:]
    assert json.loads((folder / "results.json").read_text())["n_eval_episodes"] == 1


def test_render_video_writes_mp4_and_gif(workdir, best_model):
    result = run_script(
        "evaluate.py",
        "--model",
        str(best_model),
        "--episodes",
        "0",
        "--render-video",
        "-o",
        "clips/run.mp4",
        "--video-episodes",
        "2",
        "--width",
        "160",
        "--height",
        "120",
        "--gif",
        "--env-kwargs",
        "max_episode_steps=20",
        cwd=workdir,
    )
    assert result.returncode == 0, result.stderr
    frames, fps = read_video(workdir / "clips" / "run.mp4")
    assert fps == 50  # every 2nd control step of 100 Hz: real time
    assert frames.shape == (20, 120, 160, 3)  # 2 episodes x 20 steps / 2
    assert frames.std() > 10
    assert (workdir / "clips" / "run.gif").read_bytes().startswith(b"GIF8")
    assert [p.name for p in (workdir / "clips").iterdir() if p.name.startswith(".")] == []


def limited_file_size(limit_bytes: int) -> Callable[[], None]:
    """A subprocess preexec that makes every file write past ``limit_bytes`` fail (EFBIG),
    as a full disk does, for the process and the ffmpeg it starts."""

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # fail the write instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return limit


def test_a_video_that_cannot_be_written_whole_is_one_line_and_no_file(workdir, best_model):
    clips = workdir / "full-disk"
    args = [
        sys.executable,
        str(REPO / "evaluate.py"),
        "--model",
        str(best_model),
        "--episodes",
        "0",
        "--render-video",
        "-o",
        str(clips / "run.mp4"),
        "--video-episodes",
        "1",
        "--width",
        "64",
        "--height",
        "48",
        "--env-kwargs",
        "max_episode_steps=200",
    ]
    played = subprocess.run(
        args,
        cwd=workdir,
        capture_output=True,
        text=True,
        timeout=300,
        preexec_fn=limited_file_size(4_000),
    )
    assert (
        played.returncode == 1
        and error_lines(played)
        == [
            line
            for line in error_lines(played)
            if line.startswith(f"evaluate.py: error: {clips / 'run.mp4'}: the video")
        ]
        and error_lines(played)
    ), played.stderr
    assert list(clips.iterdir()) == []  # neither a truncated mp4 nor a temporary file
    # control: the same command with room on the disk
    written = subprocess.run(args, cwd=workdir, capture_output=True, text=True, timeout=300)
    assert written.returncode == 0 and (clips / "run.mp4").stat().st_size > 4_000


def test_a_quietly_truncated_video_replaces_nothing(tmp_path, monkeypatch):
    # ffmpeg on a full disk can also exit 0 with a short file: the frames read back decide
    from minitaur_env import MinitaurBulletEnv
    from minitaur_env.training import video

    target = tmp_path / "clip.mp4"
    target.write_bytes(b"the previous video")
    env = MinitaurBulletEnv(render_mode="rgb_array", width=64, height=48)
    monkeypatch.setattr(video, "_frames_in", lambda path: 3)
    with pytest.raises(OSError, match=r"clip.mp4: the video came out with 3 of 10 frames"):
        video.record_video(env, lambda obs: np.zeros(8, np.float32), target, max_steps=20)
    env.close()
    assert target.read_bytes() == b"the previous video"
    assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]


def test_a_video_plays_its_episodes_through_the_one_episode_loop(tmp_path):
    from minitaur_env import MinitaurBulletEnv
    from minitaur_env.training import video
    from minitaur_env.training.evaluation import run_episodes

    env = MinitaurBulletEnv(render_mode="rgb_array", width=64, height=48)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (1000, 8))
    step = iter(actions)
    stats = video.record_video(
        env, lambda obs: next(step), tmp_path / "clip.mp4", episodes=2, max_steps=30, seed=7
    )
    # 100 Hz control filmed at 50 fps: a frame every other step, 15 per 30-step episode.
    assert stats["frames"] == 30 and stats["fps"] == 50
    step = iter(actions)
    played = run_episodes(lambda obs: next(step), env, 2, seed=7, max_steps=30)
    assert [record["length"] for record in played] == [30, 30]
    assert stats["returns"] == [record["return"] for record in played]
    # The control: other seeds draw other dynamics, and so other returns.
    step = iter(actions)
    other = run_episodes(lambda obs: next(step), env, 2, seed=8, max_steps=30)
    assert stats["returns"] != [record["return"] for record in other]
    env.close()


def test_default_video_name_goes_to_videos(workdir, best_model):
    result = run_main(
        evaluate.main,
        "--model",
        str(best_model),
        "--episodes",
        "0",
        "--render-video",
        "--video-episodes",
        "1",
        "--width",
        "64",
        "--height",
        "48",
        *SHORT,
        cwd=workdir,
    )
    assert result.returncode == 0, result.stderr
    videos = list((workdir / "videos").glob("MinitaurBulletEnv-v0_sac_*.mp4"))
    assert len(videos) == 1


def test_gui_mode_plays_episodes(workdir, best_model, display):
    result = run_script(
        "evaluate.py",
        "--model",
        str(best_model),
        "--episodes",
        "0",
        "--gui",
        "--video-episodes",
        "2",
        "--env-kwargs",
        "max_episode_steps=10",
        cwd=workdir,
        keep_display=True,
    )
    assert result.returncode == 0, result.stderr
    assert "gui: 2 episodes in the PyBullet window, returns " in result.stdout


def test_default_policy_is_the_best_shipped_one_else_the_latest_run(tmp_path, monkeypatch):
    from minitaur_env.training import evaluation

    shipped = tmp_path / "checkout" / "pretrained"
    shipped.mkdir(parents=True)
    for algo, score in (("sac", 3.5), ("ppo", 12.0), ("tqc", 7.0)):
        run = shipped / algo / "MinitaurBulletEnv-v0_1"
        run.mkdir(parents=True)
        (run / "MinitaurBulletEnv-v0.zip").write_bytes(b"")
        (run / "provenance.yml").write_text(f"eval_mean_return: {score}\n")
    monkeypatch.setattr(evaluation, "PRETRAINED_DIR", shipped)
    assert evaluation.find_model(None, None, None) == (
        shipped / "ppo" / "MinitaurBulletEnv-v0_1" / "MinitaurBulletEnv-v0.zip"
    )

    monkeypatch.setattr(evaluation, "PRETRAINED_DIR", tmp_path / "nothing-shipped")
    monkeypatch.chdir(tmp_path)
    for n, written_at in ((1, 2_000_000_000), (2, 1_000_000_000)):
        run = tmp_path / "logs" / "sac" / f"MinitaurBulletEnv-v0_{n}"
        run.mkdir(parents=True)
        (run / "config.yml").write_text("algo: sac\n")
        os.utime(run / "config.yml", (written_at, written_at))
        (run / "best_model.zip").write_bytes(b"")
    # The latest run is the one whose config.yml was written last, not the highest number.
    assert evaluation.find_model(None, None, None) == Path(
        "logs/sac/MinitaurBulletEnv-v0_1/best_model.zip"
    )


def _make_cartpole_model(path):
    PPO("MlpPolicy", "CartPole-v1", n_steps=16, batch_size=16, device="cpu").save(path)


@pytest.mark.parametrize(
    ("args", "message", "code"),
    [
        (["--model", "missing.zip"], "model file not found: missing.zip", 2),
        (["--model", "corrupt.zip"], "is not a Stable-Baselines3 model file", 2),
        (["--model", "cartpole.zip"], "expects observations of shape (4,)", 2),
        (["--model", "{best}", "--env", "NoSuchEnv-v1"], "unknown env id 'NoSuchEnv-v1'", 2),
        (["--model", "{best}", "--render-video", "-o", "a-file/x.mp4"], "cannot write to", 2),
        (["--model", "{best}", "--json", "a-file/x.json"], "cannot write to", 2),
        (["--model", "{best}", "--gui"], "DISPLAY", 2),
        (["--frobnicate"], "unrecognized arguments: --frobnicate", 2),
        (["-f", "empty-logs"], "no trained model found under empty-logs", 2),
    ],
)
def test_user_errors_give_one_clear_line(
    workdir, best_model, tmp_path, monkeypatch, args, message, code
):
    (tmp_path / "corrupt.zip").write_bytes(b"this is not a zip file")
    (tmp_path / "a-file").write_text("")
    _make_cartpole_model(tmp_path / "cartpole.zip")
    args = [*(a.replace("{best}", str(best_model)) for a in args), "--episodes", "1", *SHORT]
    before = sorted(p.name for p in tmp_path.rglob("*"))
    # Two cases run as a user runs the script; the others through its main() in this process.
    if "corrupt.zip" in args or "NoSuchEnv-v1" in args:
        result = run_script("evaluate.py", *args, cwd=tmp_path)
    else:
        monkeypatch.delenv("DISPLAY", raising=False)  # as run_script does
        result = run_main(evaluate.main, *args, cwd=tmp_path)
    assert result.returncode == code, result.stdout + result.stderr
    lines = error_lines(result)
    assert len(lines) == 1, result.stderr
    assert message in lines[0]
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # nothing half-written


def test_exp_id_picks_that_run_of_the_log_folder(tmp_path):
    import shutil

    shipped = Path(__file__).resolve().parents[1] / "pretrained" / "ppo" / "MinitaurBulletEnv-v0_1"
    for number in (1, 2):
        shutil.copytree(shipped, tmp_path / "logs" / "ppo" / f"MinitaurBulletEnv-v0_{number}")
    common = [
        "-f",
        "logs",
        "--algo",
        "ppo",
        "--env",
        "MinitaurBulletEnv-v0",
        "--episodes",
        "1",
        "--env-kwargs",
        "max_episode_steps=20",
    ]
    for number in (1, 2):
        played = run_main(evaluate.main, *common, "--exp-id", str(number), cwd=tmp_path)
        assert played.returncode == 0, played.stderr
        assert f"MinitaurBulletEnv-v0_{number}/MinitaurBulletEnv-v0.zip" in played.stdout
    missing = run_main(evaluate.main, *common, "--exp-id", "3", cwd=tmp_path)
    assert error_lines(missing) == [
        "evaluate.py: error: no run MinitaurBulletEnv-v0_3 under logs/ppo/"
    ]


def test_load_last_checkpoint_skips_a_torn_newest_one(tmp_path):
    import shutil

    shipped = Path(__file__).resolve().parents[1] / "pretrained" / "ppo" / "MinitaurBulletEnv-v0_1"
    run = tmp_path / "logs" / "ppo" / "MinitaurBulletEnv-v0_1"
    shutil.copytree(shipped, run)
    (run / "checkpoints").mkdir()
    shutil.copyfile(
        shipped / "MinitaurBulletEnv-v0.zip", run / "checkpoints/rl_model_100_steps.zip"
    )
    for suffix in (".pkl", ".json"):  # its statistics, as a checkpoint keeps them
        saved = run / "checkpoints" / f"rl_model_vecnormalize_100_steps{suffix}"
        shutil.copyfile(shipped / "MinitaurBulletEnv-v0" / f"vecnormalize{suffix}", saved)
    (run / "checkpoints" / "rl_model_200_steps.zip").write_bytes(b"PK\x03\x04 torn by a kill")
    last_checkpoint = ["-f", "logs", "--algo", "ppo", "--env", "MinitaurBulletEnv-v0"]
    last_checkpoint.append("--load-last-checkpoint")
    played = run_main(
        evaluate.main,
        *last_checkpoint,
        "--episodes",
        "1",
        "--env-kwargs",
        "max_episode_steps=20",
        cwd=tmp_path,
    )
    assert played.returncode == 0, played.stderr
    assert "rl_model_100_steps.zip" in played.stdout
    # With every checkpoint torn there is nothing to play: one line, not a traceback.
    (run / "checkpoints/rl_model_100_steps.zip").write_bytes(b"PK\x03\x04 torn too")
    refused = run_main(evaluate.main, *last_checkpoint, cwd=tmp_path)
    assert refused.returncode == 2
    assert error_lines(refused.stderr) == [
        f"evaluate.py: error: {Path('logs/ppo/MinitaurBulletEnv-v0_1')} has no readable checkpoint"
    ]
