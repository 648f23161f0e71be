"""What each command does with its parsed flags.

Each script (train.py, evaluate.py, ``python -m minitaur_env.sweep|package|onnx``) parses
its flags and calls one function here, which returns the exit code; errors the user can
fix end as one line. Heavy imports happen inside the functions, so that a script's
``--help`` and an ONNX evaluation need neither torch nor SB3.
"""

from __future__ import annotations

import argparse
import json
import re
import signal
import sys
import time
from datetime import datetime
from pathlib import Path

from minitaur_env.training import DEFAULT_ENV, UsageError, env_name


def train(args: argparse.Namespace, prog: str, command: str, given: set[str]) -> int:
    """Create or resume the run the flags describe, run it, and return the exit code.

    ``command`` is the command line the run folder records; ``given``, the flags typed.
    """
    from minitaur_env.training.cli import config_from_args, resume_overrides
    from minitaur_env.training.experiment import Experiment

    options = dict(
        verbose=args.verbose, progress=args.progress, num_threads=args.num_threads, command=command
    )
    if args.resume:
        experiment = Experiment.resume(
            args.resume,
            n_timesteps=args.n_timesteps,
            overrides=resume_overrides(args, given),
            device=args.device if "device" in given else None,
            trust_pickle=args.trust_pickle,
            **options,
        )
    else:
        config = config_from_args(
            args,
            seed=args.seed,
            n_envs=args.n_envs,
            vec_env=args.vec_env,
            save_freq=args.save_freq,
            video_freq=args.video_freq,
            video_length=args.video_length,
            device=args.device,
            tensorboard_log=args.tensorboard_log,
            trained_agent=args.trained_agent,
            trust_pickle=args.trust_pickle,
        )
        experiment = Experiment.create(config, args.log_folder, **options)
    result = experiment.run()
    if result.status in ("diverged", "failed"):
        print(f"{prog}: error: {result.message}", file=sys.stderr)
    elif result.message:
        print(f"\n{result.message}", file=sys.stderr)
    if result.trained_steps or result.status != "interrupted" or result.checkpoint:
        print(result.summary())
    return result.exit_code


def evaluate(args: argparse.Namespace, prog: str) -> int:
    """evaluate.py: statistics of a policy, its video, or the GUI."""
    from minitaur_env.training.evaluation import (
        OnnxPolicy,
        find_model,
        format_table,
        load_policy,
        play,
        playing_kwargs,
        run_episodes,
        summarize,
    )
    from minitaur_env.training.files import atomic_path, ensure_writable
    from minitaur_env.training.hyperparams import parse_overrides
    from minitaur_env.training.single_env import make_env
    from minitaur_env.training.video import record_video

    try:
        path = args.model or find_model(
            args.log_folder,
            args.algo,
            args.env,
            args.exp_id,
            args.load_best,
            args.load_checkpoint,
            args.load_last_checkpoint,
        )
        policy = load_policy(Path(path), args.algo, args.device, args.trust_pickle)
        if isinstance(policy, OnnxPolicy) and not args.deterministic:
            raise UsageError(f"{path} is the deterministic actor; --stochastic needs the zip")
        env_id = args.env or policy.env_id or DEFAULT_ENV
        env_kwargs = playing_kwargs(policy, parse_overrides(args.env_kwargs, "--env-kwargs"))
        video_path = None
        if args.render_video:
            stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
            default = Path("videos") / f"{env_name(env_id)}_{policy.algo}_{stamp}.mp4"
            video_path = args.output or default
            ensure_writable(video_path.parent)
        if args.json is not None:
            ensure_writable(args.json.parent)
        details = [policy.algo] + ([policy.backend] if policy.backend != "sb3" else [])
        if isinstance(policy, OnnxPolicy):
            details.append("onnxruntime, normalization in the graph")
        elif policy.normalizer is not None and policy.normalizer.norm_obs:
            details.append("observations normalized")
        elif policy.normalization_unknown:
            details.append(
                "raw observations: no VecNormalize statistics in the zip and no config.yml "
                "beside it to say it was trained without them"
            )
        print(f"policy: {policy.path} ({', '.join(details)}) on {env_id}")

        results = None
        if args.episodes:
            records = play(
                policy,
                env_id,
                env_kwargs,
                args.episodes,
                args.seed,
                args.deterministic,
                realism=args.realism,
            )
            summary = summarize(records)
            mode = "deterministic" if args.deterministic else "stochastic"
            print(f"{args.episodes} episodes, {mode}, seeds {args.seed}..")
            print(format_table(summary, args.episodes))
            results = {
                "model": str(policy.path),
                "algo": policy.algo,
                "env": env_id,
                "episodes": args.episodes,
                "seed": args.seed,
                "deterministic": args.deterministic,
                "summary": summary,
                "per_episode": records,
            }
            if args.json is not None:
                with atomic_path(args.json) as temp:
                    temp.write_text(json.dumps(results, indent=2))
                print(f"statistics: {args.json}")

        if video_path is not None:
            env = make_env(
                env_id, env_kwargs, render_mode="rgb_array", width=args.width, height=args.height
            )
            started = time.perf_counter()
            try:
                stats = record_video(
                    env,
                    lambda obs: policy.act(obs, args.deterministic),
                    video_path,
                    episodes=args.video_episodes,
                    max_steps=env.spec.max_episode_steps or 1000,
                    fps=args.video_fps,
                    seed=args.seed,
                    gif_path=video_path.with_suffix(".gif") if args.gif else None,
                )
            finally:
                env.close()
            elapsed = time.perf_counter() - started
            gif = f"; gif: {video_path.with_suffix('.gif')}" if args.gif else ""
            print(
                f"video: {video_path} ({stats['frames']} frames at {stats['fps']:g} fps, "
                f"{elapsed:.1f} s to write){gif}"
            )
        if args.gui:
            env = make_env(env_id, env_kwargs, render_mode="human")
            try:
                shown = run_episodes(
                    policy, env, args.video_episodes, args.seed, args.deterministic
                )
            finally:
                env.close()
            returns = ", ".join(f"{record['return']:.2f}" for record in shown)
            print(f"gui: {len(shown)} episodes in the PyBullet window, returns {returns}")
    except RuntimeError as error:  # a simulator failure while playing
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 1
    return 0


def sweep(args: argparse.Namespace, command: str, prog: str) -> int:
    """minitaur sweep: run, resume or summarize a sweep."""
    from minitaur_env.training.aggregate import format_rows
    from minitaur_env.training.cli import config_from_args
    from minitaur_env.training.search_space import load_search_space
    from minitaur_env.training.sweep_summary import summarize
    from minitaur_env.training.sweeps import Sweep, seed_list

    if args.summarize:
        rows = summarize(args.summarize, args.milestones)
        print(format_rows(rows))
        print(f"summary: {Path(args.summarize[0]) / 'summary.csv'}")
        return 0
    seeds = seed_list(args.seeds, args.first_seed)
    base = config_from_args(args, save_freq=args.save_freq, vec_env="dummy", device="cpu")
    sweep = Sweep(
        base=base,
        storage=args.storage,
        name=args.name or f"{args.algo}-{env_name(args.env)}",
        seeds=seeds,
        search=load_search_space(args.search) if args.search else None,
        trials=args.trials,
        scheduler=args.scheduler,
        cpus_per_trial=args.cpus_per_trial,
        gpus_per_trial=args.gpus_per_trial,
        max_concurrent=args.max_concurrent,
        address=args.address,
        command=command,
        trust_pickle=args.trust_pickle,
    )
    failures = sweep.run(resume=args.resume)
    for line in failures:
        print(line, file=sys.stderr)
    if sweep.unfinished():  # Tune returns normally after Ctrl-C, with the trials cut short
        print(
            f"sweep interrupted; continue it with: {prog} "
            f"-f {sweep.storage} --name {sweep.name} --resume",
            file=sys.stderr,
        )
        return 128 + (sweep.stopped_by or signal.SIGINT)
    rows = summarize(sweep.folder, args.milestones)
    print(format_rows(rows))
    print(f"summary: {sweep.folder / 'summary.csv'}; curves: {sweep.folder / 'curves.png'}")
    return 1 if failures else 0


def package(args: argparse.Namespace) -> int:
    """minitaur package: a Hugging Face Hub model folder, offline."""
    try:
        from minitaur_env.training.hub import package_for_hub
    except ImportError as error:
        raise UsageError(f"{error} (pip install 'minitaur-env[zoo]')") from error
    folder = package_for_hub(
        args.run_or_model,
        args.out,
        args.env,
        args.episodes,
        args.seed,
        args.video_steps,
        args.trust_pickle,
        args.replace,
    )
    print(f"hub folder: {folder}")
    return 0


def export_onnx(args: argparse.Namespace) -> int:
    """minitaur onnx: the deterministic actor as one ONNX graph."""
    from minitaur_env.training.files import ensure_writable
    from minitaur_env.training.onnx_export import export_onnx

    ensure_writable(args.output.parent)
    info = export_onnx(args.run_or_model, args.output, args.trust_pickle)
    size = args.output.stat().st_size / 1024
    print(
        f"{args.output}: {info['algo']} actor for {info['env_id']}, {size:.0f} KiB, "
        f"observation normalization {info['observation_normalization']}; "
        f"largest action difference from predict {info['max_abs_difference']:.1e}"
    )
    return 0


def ship(args: argparse.Namespace) -> int:
    """minitaur ship: select a policy on unreported seeds, and ship it."""
    from minitaur_env.training.files import ensure_writable, refuse_to_replace, write_text
    from minitaur_env.training.hyperparams import parse_overrides
    from minitaur_env.training.run_folder import RunFolder
    from minitaur_env.training.seeds import judging_block
    from minitaur_env.training.shipping import select
    from minitaur_env.training.shipping import ship as ship_policy

    select_episodes = args.episodes if args.select_episodes is None else args.select_episodes
    if min(args.episodes, select_episodes) < 1:
        raise UsageError("--episodes and --select-episodes must be at least 1")
    try:
        selection = judging_block(args.select_seed, select_episodes, "selection")
        report = judging_block(args.report_seed, args.episodes, "report")
    except ValueError as error:
        raise UsageError(str(error)) from error
    if set(selection) & set(report):  # the report must be seeds the choice never saw
        raise UsageError(
            f"selection seeds {selection.start}..{selection.stop - 1} overlap the report "
            f"seeds {report.start}..{report.stop - 1}"
        )
    runs = [RunFolder.existing(path) for path in args.runs]
    if args.ship:  # before the hours of judging
        for run in runs:  # provenance needs each run's commands
            if not run.command.is_file():
                raise UsageError(f"--ship: {run} has no command.txt saying what trained it")
        names = sorted({run.env_name for run in runs})
        # The zoo finds a run folder's files by its name, <env>_<N>.
        if not re.fullmatch(rf"({'|'.join(map(re.escape, names))})_\d+", args.ship.name):
            raise UsageError(
                f"--ship {args.ship}: a shipped folder is named as the zoo names run folders, "
                f"<env>_<N>, e.g. {args.ship.parent / (names[0] + '_1')}"
            )
        ensure_writable(args.ship.parent)
        refuse_to_replace(args.ship, args.replace, "--ship")
    if args.json:
        ensure_writable(args.json.parent)
    report = select(
        runs,
        episodes=args.episodes,
        select_episodes=args.select_episodes,
        select_seed=args.select_seed,
        report_seed=args.report_seed,
        from_steps=args.from_steps,
        only_steps=args.steps,
        final_only=args.final_only,
        also_on=[parse_overrides(flags, "--also-on") for flags in args.also_on or []],
        trust_pickle=args.trust_pickle,
    )
    if args.json:
        write_text(args.json, json.dumps(report, indent=2))
    if args.ship:
        provenance = ship_policy(report, args.ship, args.trust_pickle)
        print(
            f"shipped: {RunFolder(args.ship).zoo_model}: {provenance['eval_mean_return']:.2f}"
            f" ± {provenance['eval_std_return']:.2f}, {provenance['eval_falls']} falls on "
            "the report seeds"
        )
    return 0
