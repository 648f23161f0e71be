"""The policies shipped in pretrained/ load, fit the env and walk."""

from __future__ import annotations

import re

import pytest
import yaml

from minitaur_env.training.envs import make_env
from minitaur_env.training.evaluation import PRETRAINED_DIR, load_policy, pretrained_models
from tests.scripts import needs

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

SHIPPED = [path for _, path in pretrained_models()]


def test_something_is_shipped_with_provenance():
    assert SHIPPED, f"no policy in {PRETRAINED_DIR}"
    for path in SHIPPED:
        provenance = yaml.safe_load((path.parent / "provenance.yml").read_text())
        keys = ("algo", "env", "eval_mean_return", "eval_mean_speed_m_per_s", "eval_episodes")
        for key in (*keys, "training"):
            assert key in provenance, (path.name, key)


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_policy_walks_forward_without_falling(path):
    policy = load_policy(str(path), device="cpu")  # a path as text, as a notebook passes it
    env = make_env(policy.env_id, policy.env_kwargs)
    obs, info = env.reset(seed=2024)
    start = info["base_position"][0]
    for _ in range(300):
        obs, _, terminated, _, info = env.step(policy.act(obs))
        assert not terminated
    # The episode's own control step: under randomization 300 steps are 0.9 to 6 s.
    speed = (info["base_position"][0] - start) / (300 * env.unwrapped.dt)
    provenance = yaml.safe_load((path.parent / "provenance.yml").read_text())
    claimed = provenance["eval_mean_speed_m_per_s"]
    # The first 300 steps, the start included, should show a good part of the claimed speed.
    assert speed > 0.5 * claimed, f"{speed:.2f} m/s for a claimed mean of {claimed} m/s"
    env.close()


@pytest.mark.parametrize("path", SHIPPED, ids=[p.parent.parent.name for p in SHIPPED])
def test_each_shipped_agent_has_a_hub_folder_that_agrees_with_its_provenance(path):
    hub = needs("huggingface_hub")
    provenance = yaml.safe_load((path.parent / "provenance.yml").read_text())
    name = f"{provenance['algo']}-{provenance['env']}"
    folder = PRETRAINED_DIR / "hub" / name
    assert (folder / f"{name}.zip").read_bytes() == path.read_bytes()
    card = hub.ModelCard.load(folder / "README.md").data.to_dict()
    metric = card["model-index"][0]["results"][0]["metrics"][0]
    mean, std = provenance["eval_mean_return"], provenance["eval_std_return"]
    card_mean, _, card_std = metric["value"].split()
    assert abs(float(card_mean) - mean) <= 0.01 and abs(float(card_std) - std) <= 0.01
    assert (folder / "replay.mp4").stat().st_size > 10_000
    # The card says how the agent was trained: every command of its provenance.
    card_text = (folder / "README.md").read_text()
    block = provenance["training"]
    while block:  # a model trained on from another: every run of the chain
        for command in block.get("commands") or [block.get("command")]:
            if command:
                assert command.split("train.py", 1)[-1].strip() in card_text, command
        block = block.get("started_from") or {}


@pytest.mark.parametrize("path", SHIPPED, ids=[p.parent.parent.name for p in SHIPPED])
def test_each_hub_cards_usage_snippet_walks_the_agent_from_the_hub_files(path):
    """The card's code, as a Hub user copies it, on the folder's own files."""
    provenance = yaml.safe_load((path.parent / "provenance.yml").read_text())
    name = f"{provenance['algo']}-{provenance['env']}"
    folder = PRETRAINED_DIR / "hub" / name
    card = (folder / "README.md").read_text()
    snippet = card.split("## Usage", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
    assert f'load_from_hub("<user>/{name}"' in snippet
    # The Hub download, replaced by the files it would download; 200 steps, not 1000.
    snippet = re.sub(
        rf'load_from_hub\("<user>/{re.escape(name)}", "([^"]+)"\)',
        lambda match: repr(str(folder / match.group(1))),
        snippet.replace("from huggingface_sb3 import load_from_hub\n", ""),
    ).replace("range(1000)", "range(200)")
    # The card resets unseeded; one seeded draw of the randomized dynamics keeps the test
    # from meeting, some day, a draw under which 200 steps are short.
    assert "obs = env.reset()" in snippet
    snippet = snippet.replace("obs = env.reset()", "env.seed(2024)\nobs = env.reset()")
    namespace: dict = {}
    exec(compile(snippet, f"{name}/README.md", "exec"), namespace)
    # Half the claimed speed over the episode's own 200 control steps; a fall would have
    # reset the position to the start.
    dt = namespace["env"].venv.envs[0].unwrapped.dt
    distance = namespace["info"][0]["base_position"][0]
    assert distance > 0.5 * provenance["eval_mean_speed_m_per_s"] * 200 * dt, distance
