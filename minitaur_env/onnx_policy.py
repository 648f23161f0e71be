"""Play an exported policy (``python -m minitaur_env.onnx``) with onnxruntime alone.

No torch, no Stable-Baselines3 and no pickle: the ``.onnx`` file holds the actor with the
observation normalization folded in, and its metadata names the env it was trained on.
Install with ``pip install 'minitaur-env[onnx]'``::

    import onnxruntime as ort
    session = ort.InferenceSession("policy.onnx")
    action = session.run(None, {"obs": obs[None].astype("float32")})[0][0]
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from minitaur_env.training import UsageError

METADATA_KEY = "minitaur_env"


def load_session(source: Path | bytes) -> Any:
    """An onnxruntime session on the CPU, one thread (one action at a time is latency-bound)."""
    try:
        import onnxruntime as ort
    except ModuleNotFoundError as error:
        raise UsageError(
            "onnxruntime is not installed; playing .onnx policies needs the onnx extra: "
            "pip install 'minitaur-env[onnx]'"
        ) from error
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    data = source if isinstance(source, bytes) else _read(source)
    try:
        return ort.InferenceSession(data, options, providers=["CPUExecutionProvider"])
    except Exception as error:  # onnxruntime raises its own untyped Fail/InvalidGraph errors
        name = "the exported graph" if isinstance(source, bytes) else str(source)
        raise UsageError(f"cannot load {name} as an ONNX model: {error}") from error


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as error:
        raise UsageError(f"cannot read {path}: {error.strerror}") from error


class OnnxPolicy:
    """The interface of ``evaluation.LoadedPolicy`` (``act``, spaces, env) over an ONNX file."""

    backend = "onnx"
    normalizer = None  # folded into the graph

    def __init__(self, path: Path) -> None:
        if not path.is_file():
            raise UsageError(f"model file not found: {path}")
        self.path = path
        self.session = load_session(path)
        meta = self.session.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
        if meta is None:
            raise UsageError(
                f"{path} was not written by python -m minitaur_env.onnx: it does not say "
                "which env and normalization it was exported with"
            )
        info = json.loads(meta)
        self.algo: str = info["algo"]
        self.env_id: str | None = info.get("env_id")
        self.env_kwargs: dict[str, Any] = dict(info.get("env_kwargs") or {})
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        if [i.name for i in inputs] != ["obs"] or [o.name for o in outputs] != ["action"]:
            raise UsageError(f"{path}: expected one input 'obs' and one output 'action'")
        self.observation_shape = tuple(inputs[0].shape[1:])
        self.action_shape = tuple(outputs[0].shape[1:])

    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        if not deterministic:
            raise UsageError(f"{self.path.name} is the deterministic actor; it cannot sample")
        batch = np.asarray(obs, dtype=np.float32)[None]
        return self.session.run(None, {"obs": batch})[0][0]

    def check_spaces(self, observation_space: spaces.Space, action_space: spaces.Space) -> None:
        if self.observation_shape != observation_space.shape:
            raise UsageError(
                f"{self.path.name} expects observations of shape {self.observation_shape}, "
                f"the env gives {observation_space.shape}"
            )
        if self.action_shape != action_space.shape:
            raise UsageError(
                f"{self.path.name} gives actions of shape {self.action_shape}, "
                f"the env needs {action_space.shape}"
            )
