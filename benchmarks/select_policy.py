"""Pick a run's policy to ship without peeking at the seeds it is reported on.

Each candidate (the best model, the final model and the checkpoints from ``--from-steps``
on) plays ``--select-episodes`` (default ``--episodes``) deterministic episodes on
selection seeds (default 5000..), which neither training (seeds 0.., eval env seeds offset
by 10000) nor the README's report seeds (12345..) use. The candidate with the highest mean
among those with the fewest falls is selected, and only then played on the report seeds.
Per run, the best and final models are also reported on the report seeds: the learning
target's figure.

    python benchmarks/select_policy.py logs/screen/sac/MinitaurBulletEnv-v0_{3,4,5} \\
        --from-steps 200000 --json benchmarks/results/sac-selection.json \\
        --ship pretrained/sac/MinitaurBulletEnv-v0_1

``--ship`` writes the chosen model as a zoo-style run folder with its provenance.yml,
the run's config, evaluations and learning curve (then make its Hub folder with
``python -m minitaur_env.package``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import yaml

from minitaur_env.training import UsageError
from minitaur_env.training.aggregate import RunCurve
from minitaur_env.training.envs import make_env
from minitaur_env.training.evaluation import (
    load_policy,
    normalizer_path_for,
    run_episodes,
    summarize,
)
from minitaur_env.training.export import sbx_to_sb3
from minitaur_env.training.onnx_export import export_onnx
from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.safe_load import copy_statistics


def judge(
    model: Path,
    episodes: int,
    seed: int,
    env_id: str | None = None,
    env_kwargs: dict | None = None,
    live_actor: bool = False,
    trust_pickle: bool = False,
) -> dict[str, float]:
    """Mean, std, falls and speed of ``episodes`` deterministic episodes from ``seed``.

    ``live_actor``: a model trained with ``actor_ema`` acts with its live actor instead of
    the average, which is the model the same run would have ended with without the
    average (the average does not change training).
    """
    policy = load_policy(model, device="cpu", trust_pickle=trust_pickle)
    if live_actor:
        if getattr(policy.model.policy, "averaged_actor", None) is None:
            raise SystemExit(f"{model} has no averaged actor (actor_ema) to leave out")
        policy.model.policy.averaged_actor = None
    env = make_env(env_id or policy.env_id or "MinitaurBulletEnv-v0", env_kwargs or {})
    try:
        summary = summarize(run_episodes(policy, env, episodes, seed))
    finally:
        env.close()
    return {
        "mean": summary["return"]["mean"],
        "std": summary["return"]["std"],
        "falls": int(summary["fell"]["count"]),
        "speed": summary["speed"]["mean"],
    }


def candidates(run: RunFolder, from_steps: int, only: list[int] | None = None) -> list[Path]:
    if only:
        return [path for steps, path in run.checkpoints() if steps in only]
    found = [run.best_model, run.final_model]
    found += [path for steps, path in run.checkpoints() if steps >= from_steps]
    return [path for path in found if path.is_file()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--from-steps", type=int, default=200_000)
    parser.add_argument("--steps", type=int, nargs="+", help="only these checkpoints")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument(
        "--select-episodes", type=int,
        help="episodes per candidate on the selection seeds (default: --episodes); more "
        "of them tell a policy that falls once in 40 from one that never falls",
    )  # fmt: skip
    parser.add_argument("--select-seed", type=int, default=5000)
    parser.add_argument("--report-seed", type=int, default=12345)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--ship", type=Path, help="write the chosen model here (a zoo run folder)")
    parser.add_argument(
        "--trust-pickle", action="store_true",
        help="load pickles (SBX models, statistics without their JSON): trusted runs only",
    )  # fmt: skip
    args = parser.parse_args()
    if args.select_episodes is None:
        args.select_episodes = args.episodes
    if min(args.episodes, args.select_episodes) < 1:
        parser.error("--episodes and --select-episodes must be at least 1")
    if args.ship:  # before the hours of judging: provenance needs each run's commands
        for run_path in args.runs:
            if not RunFolder.existing(run_path).command.is_file():
                parser.error(f"--ship: {run_path} has no command.txt saying what trained it")

    report: dict = {"select_seed": args.select_seed, "report_seed": args.report_seed,
                    "episodes": args.episodes, "select_episodes": args.select_episodes,
                    "runs": {}, "selection": {}}  # fmt: skip
    print(
        f"{args.select_episodes} deterministic episodes on selection seeds "
        f"{args.select_seed}.., {args.episodes} on report seeds {args.report_seed}.."
    )
    trust = {"trust_pickle": args.trust_pickle}
    for run_path in args.runs:
        run = RunFolder.existing(run_path)
        per_run = report["runs"][str(run)] = {}
        for name, model in (("best", run.best_model), ("final", run.final_model)):
            if model.is_file():
                per_run[name] = judge(model, args.episodes, args.report_seed, **trust)
                r = per_run[name]
                print(f"{run}  {name:5s} model on report seeds: {r['mean']:6.2f} ± "
                      f"{r['std']:.2f}, {r['falls']} falls, {r['speed']:.2f} m/s")  # fmt: skip
        for model in candidates(run, args.from_steps, args.steps):
            result = judge(model, args.select_episodes, args.select_seed, **trust)
            report["selection"][str(model)] = result
            print(f"  candidate {model}: {result['mean']:6.2f} ± {result['std']:.2f}, "
                  f"{result['falls']} falls (selection seeds)")  # fmt: skip
    chosen = max(report["selection"], key=lambda m: (-report["selection"][m]["falls"],
                                                     report["selection"][m]["mean"]))  # fmt: skip
    reported = judge(Path(chosen), args.episodes, args.report_seed, **trust)
    report["chosen"] = {"model": chosen, "report": reported}
    print(
        f"chosen: {chosen}: {reported['mean']:.2f} ± {reported['std']:.2f}, "
        f"{reported['falls']} falls, {reported['speed']:.2f} m/s on the report seeds"
    )
    finals = [r["final"]["mean"] for r in report["runs"].values() if "final" in r]
    bests = [r["best"]["mean"] for r in report["runs"].values() if "best" in r]
    if bests and finals:
        print(f"median over {len(bests)} runs: best model {np.median(bests):.2f}, "
              f"final model {np.median(finals):.2f} (report seeds)")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    if args.ship:
        ship(Path(chosen), reported, report["selection"][chosen], args)


def run_of(model: Path) -> RunFolder:
    return RunFolder(model.parents[1] if model.parent.name == "checkpoints" else model.parent)


def ship(model: Path, reported: dict, selected: dict, args: argparse.Namespace) -> None:
    run, shipped = run_of(model), RunFolder(args.ship)
    config = run.read_config()
    started_from = origin_of(config.get("trained_agent"))  # before shipping may overwrite it
    shipped.path.mkdir(parents=True, exist_ok=True)
    trained_backend = config["backend"]
    if trained_backend == "sbx":  # ship the same weights in SB3's format: no JAX needed
        env = make_env(config["env"], config["env_kwargs"])
        trained = load_policy(model, device="cpu", trust_pickle=args.trust_pickle).model
        sbx_to_sb3(trained, env).save(shipped.zoo_model)
        env.close()
        config = {**config, "backend": "sb3"}
    else:
        shutil.copyfile(model, shipped.zoo_model)
    shipped.write_config(config)  # also the zoo's <env>/ files
    stats = normalizer_path_for(model)
    if stats is not None:  # the pickle for the zoo, the JSON for safe loading
        copy_statistics(stats, shipped.zoo_vecnormalize, args.trust_pickle)
    onnx = export_onnx(shipped.zoo_model, shipped.onnx_policy)  # refuses if it disagrees
    as_trained = None
    if trained_backend == "sbx":
        # Torch and XLA round differently (actions agree to 2e-6), and 1000 steps of
        # walking amplify that: the figures must be the shipped file's own, judged as
        # evaluate.py plays it (with the statistics just copied beside it).
        as_trained, reported = reported, judge(shipped.zoo_model, args.episodes, args.report_seed)
    shutil.copyfile(run.evaluations, shipped.evaluations)
    shutil.copyfile(run.learning_curve, shipped.learning_curve)
    steps = int(saved_steps(model))
    curve = RunCurve.read(run)
    minutes = float(np.interp(steps, curve.steps, curve.seconds)) / 60
    provenance = {
        "algo": config["algo"], "backend": trained_backend, "env": config["env"],
        "env_kwargs": config["env_kwargs"],
        "eval_mean_return": round(reported["mean"], 3),
        "eval_std_return": round(reported["std"], 3),
        "eval_episodes": args.episodes,
        "eval_seeds": f"{args.report_seed}..{args.report_seed + args.episodes - 1}",
        "eval_deterministic": True,
        "eval_falls": reported["falls"],
        "eval_mean_speed_m_per_s": round(reported["speed"], 3),
        "eval_command": f"python evaluate.py --model {shipped.zoo_model} "
                        f"--episodes {args.episodes}",
        "selection": {
            "rule": "most episodes without a fall, then the highest mean, among the "
                    "candidates of benchmarks/select_policy.py",
            "seeds": f"{args.select_seed}..{args.select_seed + args.select_episodes - 1}",
            "mean_return": round(selected["mean"], 3), "falls": selected["falls"],
        },
        "training": {
            "commands": run.command.read_text().strip().splitlines(),
            "seed": config["seed"],
            "model": f"{model.relative_to(run.path)} of {run.path.name}",
            "model_steps": steps,
            "trained_steps": max((steps for steps, _ in run.checkpoints()), default=steps),
            "wall_clock_min_to_model": round(minutes, 1),
            "wall_clock_note": "training time on the 2-core CPU machine, shared with other "
                               "training runs (see the README)",
        },
    }  # fmt: skip
    if as_trained is not None:
        provenance["exported"] = {
            "how": "trained with SBX (JAX); shipped with the same weights in SB3's format "
                   "by minitaur_env.training.export.sbx_to_sb3; the eval figures above are "
                   "the shipped file's",
            "sbx_model_on_the_same_seeds": {
                "mean_return": round(as_trained["mean"], 3),
                "std_return": round(as_trained["std"], 3), "falls": as_trained["falls"],
            },
        }  # fmt: skip
    provenance["onnx"] = {
        "file": shipped.onnx_policy.name,
        "max_abs_action_difference_from_predict": float(f"{onnx['max_abs_difference']:.2e}"),
    }
    if started_from:
        provenance["training"]["started_from"] = started_from
    shipped.provenance.write_text(yaml.safe_dump(provenance, sort_keys=False, width=100))
    print(f"shipped: {shipped.zoo_model}: {reported['mean']:.2f} ± {reported['std']:.2f}, "
          f"{reported['falls']} falls on the report seeds")  # fmt: skip


def origin_of(trained_agent: str | None) -> dict | None:
    """The model a run started from (train.py -i) and, if it was shipped, its training."""
    if not trained_agent:
        return None
    provenance = Path(trained_agent).parent / "provenance.yml"
    earlier = yaml.safe_load(provenance.read_text()) if provenance.is_file() else {}
    return {"trained_agent": trained_agent, **earlier.get("training", {})}


def saved_steps(model: Path) -> int:
    """The env steps a model zip was saved at (SB3's num_timesteps in its data)."""
    import zipfile

    with zipfile.ZipFile(model) as archive:
        return int(json.loads(archive.read("data"))["num_timesteps"])


if __name__ == "__main__":
    try:
        main()
    except UsageError as error:  # e.g. a pickle that needs --trust-pickle
        sys.exit(f"select_policy.py: error: {error}")
