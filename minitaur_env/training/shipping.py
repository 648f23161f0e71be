"""Shipping a policy: judge candidates on seeds no one reports, pick one, write it with
its provenance.

Selection seeds (5000..) are used neither by training nor by the report (12345..): the
seed plan (``seeds.py``) keeps every run's own seeds apart from both blocks. The figures a
shipped policy carries are its report seeds'. ``minitaur ship`` is the command;
provenance.yml is written here and nowhere else.
"""

from __future__ import annotations

import json
import shlex
import shutil
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from minitaur_env.training import DEFAULT_ENV, UsageError
from minitaur_env.training.aggregate import RunCurve
from minitaur_env.training.evaluation import load_policy, play, playing_kwargs, summarize
from minitaur_env.training.files import read_yaml, replaced_folder, write_yaml
from minitaur_env.training.onnx_export import export_onnx
from minitaur_env.training.plotting import plot_learning_curve
from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.safe_load import copy_statistics
from minitaur_env.training.seeds import REPORT_SEED, SELECTION_SEED


def judge(
    model: Path,
    episodes: int,
    seed: int,
    overrides: dict[str, Any] | None = None,
    *,
    env: tuple[str, dict[str, Any]] | None = None,
    live_actor: bool = False,
    trust_pickle: bool = False,
) -> dict[str, float]:
    """Mean, std, falls and speed of ``episodes`` deterministic episodes from ``seed``.

    Played as evaluate.py plays it: on the policy's own training env and kwargs, with
    ``overrides`` changing some of them; or, with ``env`` (id, kwargs), on exactly that.
    ``live_actor``: a model trained with ``actor_ema`` acts with its live actor instead of
    the average, which is the model the same run would have ended with without the
    average (the average does not change training).
    """
    policy = load_policy(model, device="cpu", trust_pickle=trust_pickle)
    if live_actor:
        if getattr(policy.model.policy, "averaged_actor", None) is None:
            raise UsageError(f"{model} has no averaged actor (actor_ema) to leave out")
        policy.model.policy.averaged_actor = None
    if env is None:
        env = (policy.env_id or DEFAULT_ENV, playing_kwargs(policy, overrides or {}))
    summary = summarize(play(policy, *env, episodes, seed))
    return {
        "mean": summary["return"]["mean"],
        "std": summary["return"]["std"],
        "falls": int(summary["fell"]["count"]),
        "speed": summary["speed"]["mean"],
    }


def condition_label(overrides: dict[str, Any]) -> str:
    """``--env-kwargs`` flags, quoted for a shell, that give these overrides, e.g.
    ``dynamics_ranges=classic realism=classic``."""
    return " ".join(
        shlex.quote(f"{k}={v if isinstance(v, str) else json.dumps(v, separators=(',', ':'))}")
        for k, v in overrides.items()
    )


def candidates(run: RunFolder, from_steps: int, only: list[int] | None = None) -> list[Path]:
    if only:
        return [path for steps, path in run.checkpoints() if steps in only]
    found = [run.best_model, run.final_model]
    found += [path for steps, path in run.checkpoints() if steps >= from_steps]
    return [path for path in found if path.is_file()]


def select(
    runs: list[RunFolder],
    *,
    episodes: int = 20,
    select_episodes: int | None = None,
    select_seed: int = SELECTION_SEED,
    report_seed: int = REPORT_SEED,
    from_steps: int = 200_000,
    only_steps: list[int] | None = None,
    final_only: bool = False,
    also_on: list[dict[str, Any]] | None = None,
    trust_pickle: bool = False,
    log: Callable[[str], Any] = print,
) -> dict[str, Any]:
    """Judge every candidate of ``runs`` on the selection seeds and pick one.

    Candidates: each run's best model, final model and checkpoints from ``from_steps`` on
    (``only_steps``: just those checkpoints; ``final_only``: just the final models, the
    models the training command ends with). Each plays on its own training env and, for
    each of ``also_on``, on that env with those kwargs changed. The pick has the fewest
    falls over all of them, then the highest mean averaged over them; only then is it
    played on the report seeds, under each condition. Each run's best and final models
    are also judged on the report seeds (own env). Returns the whole report.
    """
    conditions = {"": {}, **{condition_label(kwargs): kwargs for kwargs in also_on or []}}
    if len(conditions) != 1 + len(also_on or []):
        raise UsageError("--also-on: each condition must change the env, and only once")
    select_episodes = episodes if select_episodes is None else select_episodes
    if min(episodes, select_episodes) < 1:
        raise UsageError("--episodes and --select-episodes must be at least 1")
    report: dict[str, Any] = {
        "select_seed": select_seed,
        "report_seed": report_seed,
        "episodes": episodes,
        "select_episodes": select_episodes,
        "final_only": final_only,
        "also_on": {label: kwargs for label, kwargs in conditions.items() if label},
        "runs": {},
        "selection": {},
    }
    log(
        f"{select_episodes} deterministic episodes on selection seeds {select_seed}.., "
        f"{episodes} on report seeds {report_seed}.."
    )
    judged: dict[tuple[str, int, int, str], dict[str, float]] = {}

    def judged_once(model: Path, count: int, seed: int, label: str) -> dict[str, float]:
        # Deterministic episodes of one model from one seed always read the same, and the
        # chosen model is most often a run's best or final model, already played on the
        # report seeds: a second playing (20 episodes of up to 1000 steps) adds nothing.
        key = (str(model), count, seed, label)
        if key not in judged:
            judged[key] = judge(model, count, seed, conditions[label], trust_pickle=trust_pickle)
        return dict(judged[key])  # a copy: a report written as YAML holds no aliases

    for run in runs:
        per_run = report["runs"][str(run)] = {}
        for name, model in (("best", run.best_model), ("final", run.final_model)):
            if model.is_file():
                result = per_run[name] = judged_once(model, episodes, report_seed, "")
                log(f"{run}  {name:5s} model on report seeds: {_figures(result)}")
        if final_only:
            found = [run.final_model] if run.final_model.is_file() else []
        else:
            found = candidates(run, from_steps, only_steps)
        for model in found:
            results = {
                label: judged_once(model, select_episodes, select_seed, label)
                for label in conditions
            }
            result = report["selection"][str(model)] = _combined(results)
            log(f"  candidate {model}: {_figures(result)} (selection seeds)")
    if not report["selection"]:
        raise UsageError("no candidate model in " + ", ".join(str(run) for run in runs))
    chosen = max(
        report["selection"],
        key=lambda m: (-report["selection"][m]["falls"], report["selection"][m]["mean"]),
    )
    reported = {
        label: judged_once(Path(chosen), episodes, report_seed, label) for label in conditions
    }
    report["chosen"] = {"model": chosen, "report": reported.pop("")}
    if reported:
        report["chosen"]["also_on"] = reported
    log(f"chosen: {chosen}: {_figures(report['chosen']['report'])} on the report seeds")
    for label, result in reported.items():
        log(f"  with --env-kwargs {label}: {_figures(result)}")
    finals = [r["final"]["mean"] for r in report["runs"].values() if "final" in r]
    bests = [r["best"]["mean"] for r in report["runs"].values() if "best" in r]
    if bests and finals:
        log(
            f"median over {len(bests)} runs: best model {np.median(bests):.2f}, "
            f"final model {np.median(finals):.2f} (report seeds)"
        )
    return report


def _combined(results: dict[str, dict[str, float]]) -> dict[str, Any]:
    """One candidate's figures over its conditions ("": its own env): falls summed, mean
    averaged; a single condition's figures as they are."""
    if len(results) == 1:
        return results[""]
    return {
        "mean": float(np.mean([r["mean"] for r in results.values()])),
        "falls": sum(r["falls"] for r in results.values()),
        "conditions": results,
    }


def _figures(result: dict[str, Any]) -> str:
    if "conditions" in result:
        each = "; ".join(
            f"{label or 'own env'}: {_figures(r)}" for label, r in result["conditions"].items()
        )
        return f"{result['mean']:6.2f} mean, {result['falls']} falls in all ({each})"
    return (
        f"{result['mean']:6.2f} ± {result['std']:.2f}, {result['falls']} falls, "
        f"{result['speed']:.2f} m/s"
    )


def ship(report: dict[str, Any], target: Path, trust_pickle: bool = False) -> dict[str, Any]:
    """Write the report's chosen model as a zoo run folder at ``target``, with its
    statistics, ONNX actor, evaluations, learning curve and provenance.yml. Returns the
    provenance."""
    config = RunFolder.of_model(Path(report["chosen"]["model"])).read_config()
    started_from = origin_of(config.get("trained_agent"))  # before shipping may overwrite it
    # Written aside, swapped in whole: a failure leaves an earlier shipped folder intact.
    with replaced_folder(target) as staged:
        return _write_shipped(
            report, RunFolder(staged), Path(target), config, started_from, trust_pickle
        )


def _write_shipped(
    report: dict[str, Any],
    shipped: RunFolder,
    target: Path,
    config: dict[str, Any],
    started_from: dict | None,
    trust_pickle: bool,
) -> dict[str, Any]:
    """``ship``'s files, written into ``shipped`` (the staged folder); the provenance
    names the files where they will be, under ``target``."""
    model = Path(report["chosen"]["model"])
    reported, selected = report["chosen"]["report"], report["selection"][str(model)]
    also_on = report["chosen"].get("also_on", {})
    episodes, report_seed = report["episodes"], report["report_seed"]
    run = RunFolder.of_model(model)
    published_model = target / shipped.zoo_model.name
    trained_backend = config["backend"]
    if trained_backend == "sbx":  # ship the same weights in SB3's format: no JAX needed
        from minitaur_env.training.export import sbx_to_sb3
        from minitaur_env.training.single_env import make_env

        env = make_env(config["env"], config["env_kwargs"])
        trained = load_policy(model, device="cpu", trust_pickle=trust_pickle).model
        sbx_to_sb3(trained, env).save(shipped.zoo_model)
        env.close()
        config = {**config, "backend": "sb3"}
    else:
        shutil.copyfile(model, shipped.zoo_model)
    shipped.write_config(config)  # also the zoo's <env>/ files
    stats = RunFolder.of_model(model).vecnormalize_for(model)
    if stats is not None:  # the pickle for the zoo, the JSON for safe loading
        copy_statistics(stats, shipped.zoo_vecnormalize, trust_pickle)
    onnx = export_onnx(shipped.zoo_model, shipped.onnx_policy)  # refuses if it disagrees
    as_trained = None
    if trained_backend == "sbx":
        # Torch and XLA round differently (actions agree to 2e-6), and 1000 steps of
        # walking amplify that: the figures must be the shipped file's own, judged as
        # evaluate.py plays it (with the statistics just copied beside it).
        as_trained, reported = reported, judge(shipped.zoo_model, episodes, report_seed)
        also_on = {
            label: judge(shipped.zoo_model, episodes, report_seed, kwargs)
            for label, kwargs in report["also_on"].items()
        }
    shutil.copyfile(run.evaluations, shipped.evaluations)
    if run.learning_curve.is_file():
        shutil.copyfile(run.learning_curve, shipped.learning_curve)
    else:  # a kept run (benchmarks/keep_runs.py) holds the evaluations, not the figure
        plot_learning_curve(
            run.evaluations, shipped.learning_curve, title=f"{config['algo']} on {config['env']}"
        )
    steps = int(saved_steps(model))
    curve = RunCurve.read(run)
    minutes = float(np.interp(steps, curve.steps, curve.seconds)) / 60
    provenance = {
        "algo": config["algo"],
        "backend": trained_backend,
        "env": config["env"],
        "env_kwargs": config["env_kwargs"],
        "eval_mean_return": round(reported["mean"], 3),
        "eval_std_return": round(reported["std"], 3),
        "eval_episodes": episodes,
        "eval_seeds": f"{report_seed}..{report_seed + episodes - 1}",
        "eval_deterministic": True,
        "eval_falls": reported["falls"],
        "eval_mean_speed_m_per_s": round(reported["speed"], 3),
        "eval_command": f"python evaluate.py --model {published_model} --episodes {episodes}",
        "eval_also_on": [
            {
                "env_kwargs": report["also_on"][label],
                "mean_return": round(result["mean"], 3),
                "std_return": round(result["std"], 3),
                "falls": result["falls"],
                "mean_speed_m_per_s": round(result["speed"], 3),
                "command": f"python evaluate.py --model {published_model} "
                f"--episodes {episodes} --env-kwargs {label}",
            }
            for label, result in also_on.items()
        ],
        "selection": {
            "rule": "most episodes without a fall, then the highest mean, among "
            + (
                "the runs' final models (no checkpoint picking)"
                if report["final_only"]
                else "each run's best model, final model and checkpoints"
            )
            + (
                ", falls summed and means averaged over its own env and "
                + "; ".join(f"--env-kwargs {label}" for label in also_on)
                if also_on
                else ""
            )
            + " (python -m minitaur_env.ship)",
            "seeds": f"{report['select_seed']}.."
            f"{report['select_seed'] + report['select_episodes'] - 1}",
            "mean_return": round(selected["mean"], 3),
            "falls": selected["falls"],
            "candidates": {
                candidate: f"{result['mean']:.2f}, {result['falls']} falls"
                for candidate, result in report["selection"].items()
            },
        },
        "training": {
            "commands": run.command.read_text().strip().splitlines(),
            "seed": config["seed"],
            "model": f"{model.relative_to(run.path)} of {run.path}",
            "model_steps": steps,
            "trained_steps": max((steps for steps, _ in run.checkpoints()), default=steps),
            # Hundredths: a short run's seconds must not round to 0.0 minutes.
            "wall_clock_min_to_model": round(minutes, 2) if np.isfinite(minutes) else None,
            "wall_clock_note": "training minutes as the run's monitor files recorded them, "
            "on the machine that trained it (a shared one runs slower)",
        },
    }
    if not also_on:
        del provenance["eval_also_on"]
    if as_trained is not None:
        provenance["exported"] = {
            "how": "trained with SBX (JAX); shipped with the same weights in SB3's format "
            "by minitaur_env.training.export.sbx_to_sb3; the eval figures above are "
            "the shipped file's",
            "sbx_model_on_the_same_seeds": {
                "mean_return": round(as_trained["mean"], 3),
                "std_return": round(as_trained["std"], 3),
                "falls": as_trained["falls"],
            },
        }
    provenance["onnx"] = {
        "file": shipped.onnx_policy.name,
        "max_abs_action_difference_from_predict": float(f"{onnx['max_abs_difference']:.2e}"),
    }
    if started_from:
        provenance["training"]["started_from"] = started_from
    write_yaml(shipped.provenance, provenance, sort_keys=False)
    return provenance


def origin_of(trained_agent: str | None) -> dict | None:
    """The model a run started from (train.py -i) and how that model was trained: its
    provenance's training if it was shipped, else its own run folder's command and seed
    (a kept run, say), so that the whole chain is written by code."""
    if not trained_agent:
        return None
    model = Path(trained_agent)
    run = RunFolder.of_model(model)
    if run.provenance.is_file():
        earlier = read_yaml(run.provenance).get("training", {})
    elif run.command.is_file() and run.config.is_file() and model.is_file():
        earlier = {
            "commands": run.command.read_text().strip().splitlines(),
            "seed": run.read_config()["seed"],
            "model": f"{model.relative_to(run.path)} of {run.path}",
            "model_steps": saved_steps(model),
        }
    else:
        earlier = {}
    return {"trained_agent": trained_agent, **earlier}


def saved_steps(model: Path) -> int:
    """The env steps a model zip was saved at (SB3's num_timesteps in its data)."""
    with zipfile.ZipFile(model) as archive:
        return int(json.loads(archive.read("data"))["num_timesteps"])
