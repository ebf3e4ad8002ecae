"""Share trained runs on the Hugging Face Hub with huggingface_hub: build a model folder with a
model card, upload it, and download a model back into rl-zoo's log layout.

The folder holds ``<algo>-<env name>.zip`` (the SB3 model), ``config.yml`` / ``config.json`` (the
hyperparameters, scenario keys included), ``results.json`` (a fresh seeded evaluation),
``replay.mp4`` and ``README.md`` (model card with model-index metadata, usage and citation).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path
from typing import Any

import httpx2  # huggingface_hub's HTTP client: its errors cover Hub errors (HfHubHTTPError) and the network
import yaml
from huggingface_hub import (
    EvalResult,
    HfApi,
    ModelCard,
    ModelCardData,
    get_token,
    snapshot_download,
)
from huggingface_hub.errors import LocalEntryNotFoundError
from rl_zoo3.utils import EnvironmentName, get_latest_run_id
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_marl.algos import get_algo
from sb3_marl.algos.common.policies import model_policy
from sb3_marl.common.files import write_text
from sb3_marl.envs import scenario_of
from sb3_marl.envs.config import LANE_CHANGE, MERGE
from sb3_marl.evaluation.trips import traffic_table, trips_csv
from sb3_marl.evaluation.video import record_video
from sb3_marl.runs.folders import Run

CITATION = """@article{zhou2022multi,
  title   = {Multi-agent reinforcement learning for cooperative lane changing of connected and
             autonomous vehicles in mixed traffic},
  author  = {Zhou, Wei and Chen, Dong and Yan, Jun and Li, Zhaojian and Yin, Huilin and Ge, Wanchen},
  journal = {Autonomous Intelligent Systems},
  year    = {2022},
  note    = {arXiv:2111.06318}
}"""

MERGE_CITATION = """@article{chen2023deep,
  title   = {Deep multi-agent reinforcement learning for highway on-ramp merging in mixed traffic},
  author  = {Chen, Dong and Hajidavalloo, Mohammad R. and Li, Zhaojian and Chen, Kaian and Wang, Yongqiang
             and Jiang, Longsheng and Wang, Yue},
  journal = {IEEE Transactions on Intelligent Transportation Systems},
  year    = {2023},
  note    = {arXiv:2105.05701}
}"""

#: The scenario's description and citation on the card, for the lane change and the merge.
SCENARIO_TEXT = {
    LANE_CHANGE: (
        "the cooperative lane-changing\nscenario of Zhou, Chen et al. (two-lane 520 m highway with human-driven vehicles)",
        CITATION,
    ),
    MERGE: (
        "the on-ramp merging\nscenario of Chen et al. (MARL_CAVs: a one-lane highway joined by a ramp, with human-driven\n"
        "vehicles)",
        MERGE_CITATION,
    ),
}

#: metric of results.json -> (model-index metric type, format of its value)
CARD_METRICS = {
    "collision_rate": "collision_rate",
    "success_rate": "success_rate",
    "speed_mean": "mean_speed_m_per_s",
    "acceleration_std": "acceleration_std_m_per_s2",
}


#: Rows of the card's evaluation table: title -> its cell from a summary.
CARD_ROWS = (
    ("episode return (sum over steps of the mean AV reward)", lambda s: f"{s['return_mean']:.2f} ± {s['return_std']:.2f}"),
    ("collision rate", lambda s: f"{s['collision_rate']:.2f}"),
    ("success rate (no crash)", lambda s: f"{s['success_rate']:.2f}"),
    ("mean speed [m/s]", lambda s: f"{s['speed_mean']:.2f}"),
    ("mean headway [m]", lambda s: f"{s['headway_mean']:.1f}"),
    ("acceleration std [m/s²]", lambda s: f"{s['acceleration_std']:.3f}"),
    ("lane changes per episode", lambda s: f"{s['lane_changes_per_episode']:.2f}"),
    ("yields per episode (an AV slowing for another's lane change)", lambda s: f"{s.get('yields_per_episode', 0):.2f}"),
    ("safety-supervisor interventions (share of AV-steps)", lambda s: f"{s['intervention_rate']:.3f}"),
)


class HubError(RuntimeError):
    """Uploading or downloading failed: no token, network or Hub error (the message says which)."""


def model_file_name(algo: str, env_id: str) -> str:
    return f"{algo}-{EnvironmentName(env_id)}.zip"


def build_model_folder(
    run: Run,
    folder: str | Path,
    repo_id: str,
    n_eval_episodes: int = 10,
    seed: int = 10_000,
    video: bool = True,
    model: BaseAlgorithm | None = None,
) -> Path:
    """Write the model folder of ``run`` (see module doc) into ``folder``; returns it.

    :param model: the run's model, loaded already (e.g. with ``trust_remote_code``); default: loaded as data
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    model = model if model is not None else run.load_model("cpu")
    shutil.copyfile(run.model_path, folder / model_file_name(run.algo, run.env_id))
    write_text(folder / "config.yml", yaml.safe_dump(_plain(run.hyperparams), sort_keys=True))
    write_text(folder / "config.json", json.dumps(_plain(run.hyperparams), indent=2, sort_keys=True))

    results = run.evaluate(model, n_eval_episodes, seed, traffic=True)
    trips = [
        {"supervisor": name, **trip}
        for name, r in (("on", results), ("off", results["supervisor_off"]))
        for trip in r.pop("trips")
    ]
    write_text(folder / "trips.csv", trips_csv(trips))
    write_text(folder / "results.json", json.dumps(results, indent=2))
    if video:
        record_video(model_policy(model), run.env_id, folder / "replay.mp4", 1, seed, run.env_config)
    write_text(folder / "README.md", str(model_card(results, repo_id)))
    return folder


#: The model card's text (markdown), filled in by :func:`model_card`.
CARD_BODY = """
# {ALGO} on {env_id}

A policy shared by all connected autonomous vehicles (AVs) of {scenario}, trained with
sb3-marl (`{algo}`: {learner} with one policy shared by all AVs),
{num_timesteps} timesteps (AV-steps).

## Evaluation

{episodes} seeded episodes (seeds {first_seed}..{last_seed}), {protocol}:
with the priority-based safety supervisor (the authors' protocol) and without it (the policy alone),
on the same episodes.

| metric | supervisor on | supervisor off (policy alone) |
|---|---|---|
{rows}
{traffic}
## Usage

Install sb3-marl from its source (it is not on PyPI): `pip install torch==2.13.0` (or any torch 2
build), then `pip install .` in a clone of the repository, or the wheel built there
(`pip wheel . --no-deps -w dist`, then `pip install dist/sb3_marl-*.whl`). Then with the command
line (rl-zoo's layout):

```bash
sb3-marl load-from-hub --repo-id {repo_id} -f logs
sb3-marl evaluate --algo {algo} --env {env_id} -f logs
sb3-marl record-video --algo {algo} --env {env_id} -f logs
```

or in Python (the evaluation protocol above: actions sampled from the policy, the scenario
configured as in training):

```python
import gymnasium as gym
from huggingface_hub import hf_hub_download

from sb3_marl.algos import get_algo
from sb3_marl.envs import scenario_of
from sb3_marl.envs.config import LANE_CHANGE, MERGE
from sb3_marl.evaluation import run_episodes
from sb3_marl.algos.common.policies import model_policy

model = get_algo("{algo}").load(hf_hub_download(repo_id="{repo_id}", filename="{model_file}"))
env = gym.make("{env_id}", config={env_config}).unwrapped
records = run_episodes(env, model_policy(model), n_episodes=3, seed=10_000)
print("episode returns:", [round(record.episode_return, 2) for record in records])
```

Hyperparameters: `config.yml`. Evaluation: `results.json`; every vehicle's trip: `trips.csv`. Replay: `replay.mp4`.

## Citation

```bibtex
{citation}
```
"""

#: The model card's tags (the Hub's search).
CARD_TAGS = (
    "reinforcement-learning",
    "deep-reinforcement-learning",
    "stable-baselines3",
    "multi-agent-reinforcement-learning",
    "autonomous-driving",
    "sb3-marl",
)


def _eval_results(results: dict[str, Any]) -> list[EvalResult]:
    """The model-index entries of ``results`` (a results.json), with the policy alone's where evaluated."""
    env_id = results["env_id"]
    evaluation = {"task_type": "reinforcement-learning", "dataset_type": env_id, "dataset_name": env_id}

    def metric(name: str, value: Any) -> EvalResult:
        return EvalResult(**evaluation, metric_type=name, metric_name=name, metric_value=value)

    # huggingface_sb3's conventions: metric type and name "mean_reward", value "mean +/- std"
    entries = [metric("mean_reward", f"{results['return_mean']:.2f} +/- {results['return_std']:.2f}")]
    entries += [metric(name, round(results[key], 4)) for key, name in CARD_METRICS.items()]
    alone = results.get("supervisor_off")
    if alone:  # the policy without the safety supervisor
        entries += [
            metric("mean_reward_supervisor_off", f"{alone['return_mean']:.2f} +/- {alone['return_std']:.2f}"),
            metric("collision_rate_supervisor_off", round(alone["collision_rate"], 4)),
        ]
    return entries


def model_card(results: dict[str, Any], repo_id: str) -> ModelCard:
    """A model card whose model-index carries the evaluation of ``results`` (a results.json)."""
    algo, env_id = results["algo"], results["env_id"]
    scenario, citation = SCENARIO_TEXT[scenario_of(env_id)]
    alone = results.get("supervisor_off")
    rows = "\n".join(f"| {title} | {cell(results)} | {cell(alone) if alone else '—'} |" for title, cell in CARD_ROWS)
    data = ModelCardData(
        library_name="stable-baselines3",
        model_name=f"{algo.upper()}-{env_id}",
        eval_results=_eval_results(results),
        tags=[env_id, *CARD_TAGS],
    )
    by_protocol = [("on", results), ("off", alone or {})]
    traffic_rows = [({"supervisor": name}, r["traffic"]) for name, r in by_protocol if "traffic" in r]
    traffic = (
        "\n## Traffic\n\nEvery vehicle, AVs and HDVs, on the same episodes (sb3-marl's docs: Traffic impact):\n\n"
        + traffic_table(traffic_rows)
        + "\n"
        if traffic_rows
        else ""
    )
    body = CARD_BODY.format(
        traffic=traffic,
        ALGO=algo.upper(),
        algo=algo,
        env_id=env_id,
        scenario=scenario,
        learner=get_algo(algo).__name__,
        num_timesteps=results["num_timesteps"],
        episodes=results["episodes"],
        first_seed=results["seeds"][0],
        last_seed=results["seeds"][1],
        protocol=results["protocol"],
        rows=rows,
        repo_id=repo_id,
        model_file=model_file_name(algo, env_id),
        env_config=repr(dict(results.get("env_config") or {})),
        citation=citation,
    )
    return ModelCard(f"---\n{data.to_yaml()}\n---\n{body}")


def push_folder(folder: str | Path, repo_id: str, commit_message: str, token: str | None = None, private: bool = False) -> str:
    """Create ``repo_id`` if needed and upload ``folder``; returns the commit URL.

    :raises HubError: without a token, or on a network / Hub error (the folder stays in place)
    """
    token = token or get_token()
    if token is None:
        raise HubError(
            "No Hugging Face token: run `hf auth login` or set HF_TOKEN. "
            f"The model folder is ready in {folder}; nothing was uploaded."
        )
    api = HfApi(token=token)
    try:
        api.create_repo(repo_id, exist_ok=True, private=private)
        commit = api.upload_folder(repo_id=repo_id, folder_path=str(folder), commit_message=commit_message)
    except (httpx2.HTTPError, OSError) as error:
        raise HubError(f"Upload of {folder} to {repo_id} failed: {error}. The model folder stays in {folder}.") from None
    return str(commit.commit_url)


def load_from_hub(repo_id: str, log_folder: str | Path, token: str | None = None) -> Path:
    """Download ``repo_id`` into a new run folder ``<log_folder>/<algo>/<env name>_<id>/`` laid out
    as ``train`` writes it, so ``evaluate`` / ``enjoy`` / ``record-video`` run on it; returns it.

    :raises HubError: on a network / Hub error or a repo that is not an sb3-marl model
    """
    with tempfile.TemporaryDirectory() as download:
        try:
            snapshot = Path(snapshot_download(repo_id, token=token, local_dir=download))
        except (
            httpx2.HTTPError,
            LocalEntryNotFoundError,
            OSError,
            ValueError,
        ) as error:  # ValueError: a file name leaving the folder
            raise HubError(f"Download of {repo_id} failed: {error}") from None
        return _place_run(repo_id, snapshot, Path(log_folder))


def _place_run(repo_id: str, snapshot: Path, log_folder: Path) -> Path:
    """Copy a downloaded model folder into a new run folder of the log layout."""
    from sb3_marl.algos import ALGO_NAMES
    from sb3_marl.envs import SCENARIO_IDS

    results_path = snapshot / "results.json"
    if not results_path.is_file():
        raise HubError(f"{repo_id} is not an sb3-marl model: it has no results.json.")
    try:
        results = json.loads(results_path.read_text())
    except (ValueError, UnicodeDecodeError) as error:
        raise HubError(f"{repo_id}: its results.json is not JSON ({error}).") from None
    algo, env_id = (results.get(key) if isinstance(results, dict) else None for key in ("algo", "env_id"))
    if algo not in ALGO_NAMES:
        raise HubError(f"{repo_id}: its results.json names the algorithm {algo!r}, not one of {list(ALGO_NAMES)}.")
    if env_id not in SCENARIO_IDS:
        raise HubError(f"{repo_id}: its results.json names the env {env_id!r}, not one of {SCENARIO_IDS}.")
    model_path = snapshot / model_file_name(algo, str(env_id))
    if not model_path.is_file():
        raise HubError(f"{repo_id} has no model file {model_path.name}.")
    env_name = EnvironmentName(env_id)
    algo_folder = Path(log_folder) / algo
    run = algo_folder / f"{env_name}_{get_latest_run_id(str(algo_folder), env_name) + 1}"
    (run / str(env_name)).mkdir(parents=True)
    shutil.copyfile(model_path, run / f"{env_name}.zip")
    if (snapshot / "config.yml").is_file():
        shutil.copyfile(snapshot / "config.yml", run / str(env_name) / "config.yml")
    for name in ("results.json", "README.md", "replay.mp4"):
        if (snapshot / name).is_file():
            shutil.copyfile(snapshot / name, run / name)
    return run


def _plain(value: Any) -> Any:
    """Hyperparameters as plain YAML/JSON types (rl_zoo3 stores OrderedDicts and tuples)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return str(value)


__all__ = ["HubError", "build_model_folder", "load_from_hub", "model_card", "push_folder"]
