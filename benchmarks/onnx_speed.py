"""One observation to one action: onnxruntime against SB3's predict and a bare torch forward.

For each shipped policy: the exported ``policy.onnx`` (normalization in the graph) run by
onnxruntime on one thread; SB3's ``predict`` with the VecNormalize statistics applied
first, as ``evaluate.py`` acts; and the same graph as a torch module called under
``no_grad`` (the fastest a torch deployment gets without compiling). The three are
interleaved in rounds so that a busy machine slows them alike; the median per action
over all rounds is printed, with the ONNX file's size.

    python benchmarks/onnx_speed.py --actions 2000 --rounds 5
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import torch

from minitaur_env.onnx_policy import OnnxPolicy
from minitaur_env.training.evaluation import PRETRAINED_DIR, load_policy
from minitaur_env.training.onnx_export import DeterministicActor


def per_action_us(act: Callable[[np.ndarray], object], observations: np.ndarray) -> float:
    started = time.perf_counter()
    for obs in observations:
        act(obs)
    return (time.perf_counter() - started) / len(observations) * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--actions", type=int, default=2000, help="actions per round and path")
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    print("per action, median of rounds (µs); one thread each")
    print(
        f"{'policy':<8}{'onnxruntime':>13}{'SB3 predict':>13}{'torch forward':>15}"
        f"{'predict/onnx':>14}{'onnx size':>11}"
    )
    for onnx_file in sorted(PRETRAINED_DIR.glob("*/MinitaurBulletEnv-v0_1/policy.onnx")):
        model = load_policy(onnx_file.with_name("MinitaurBulletEnv-v0.zip"), device="cpu")
        onnx = OnnxPolicy(onnx_file)
        module = DeterministicActor(model).eval()

        def torch_forward(obs: np.ndarray, module: torch.nn.Module = module) -> object:
            with torch.no_grad():
                return module(torch.as_tensor(obs[None]))[0].numpy()

        paths = {"onnx": onnx.act, "predict": model.act, "torch": torch_forward}
        inputs = model.model.observation_space.shape[0]  # 84 for a policy seeing 3 observations
        observations = rng.normal(size=(args.actions, inputs)).astype(np.float32)
        for act in paths.values():  # warm-up
            per_action_us(act, observations[:100])
        timings: dict[str, list[float]] = {name: [] for name in paths}
        for _ in range(args.rounds):
            for name, act in paths.items():
                timings[name].append(per_action_us(act, observations))
        median = {name: float(np.median(values)) for name, values in timings.items()}
        size = onnx_file.stat().st_size / 1024
        algo = onnx_file.parents[1].name
        print(
            f"{algo:<8}{median['onnx']:>13.1f}{median['predict']:>13.1f}{median['torch']:>15.1f}"
            f"{median['predict'] / median['onnx']:>13.1f}x{size:>8.0f} KiB"
        )


if __name__ == "__main__":
    main()
