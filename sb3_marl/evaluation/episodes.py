"""The one episode runner (evaluation, videos, reports and the CLI call it) and the evaluation
protocols: every evaluation scores a policy under both :data:`SUPERVISOR_PROTOCOLS`, with the
safety supervisor (the authors' protocol) and without it (the policy alone).

A policy is any callable ``policy(env, obs) -> actions`` (one action per AV);
:func:`sb3_marl.algos.common.policies.model_policy` makes one of an SB3 model.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import torch as th
from tqdm import tqdm

from sb3_marl.envs import av_counts, make_scenario
from sb3_marl.envs.config import SUPERVISOR_PROTOCOLS, with_supervisor
from sb3_marl.envs.lane_change_env import LaneChangeEnv
from sb3_marl.evaluation.metrics import EpisodeRecord, EpisodeTrace, summarize
from sb3_marl.evaluation.trips import TripRecorder

Policy = Callable[[LaneChangeEnv, np.ndarray], np.ndarray]

StepHook = Callable[[LaneChangeEnv, dict], None]


@contextmanager
def _seeded_global_generators(seed: int) -> Iterator[None]:
    """torch's and numpy's global generators seeded with ``seed`` inside, their states outside as before."""
    state = np.random.get_state()
    with th.random.fork_rng():
        th.manual_seed(seed)
        np.random.seed(seed)
        try:
            yield
        finally:
            np.random.set_state(state)


def run_episodes(
    env: LaneChangeEnv, policy: Policy, n_episodes: int, seed: int = 0, on_step: StepHook | None = None
) -> list[EpisodeRecord]:
    """Play ``n_episodes`` episodes with seeds ``seed, seed + 1, ...``: the one episode runner of
    evaluation, videos and reports.

    Episode ``k`` also seeds torch's and numpy's global generators with ``seed + k`` (the
    actor-critics sample with torch, MADQN's ε-greedy draws with numpy, as SB3's DQN), each inside a
    fork of its random state, so sampled actions are reproducible and a training run's own random
    streams are untouched.

    :param on_step: called as ``on_step(env, info)`` after the reset (``info["step"] == 0``) and
        after every step of every episode
    """
    records = []
    for episode in range(n_episodes):
        with _seeded_global_generators(seed + episode):
            obs, info = env.reset(seed=seed + episode)
            trace = EpisodeTrace(seed + episode, env.n_avs)
            trace.record(env, info)
            if on_step is not None:
                on_step(env, info)
            record, done = EpisodeRecord(rule_actions=info.get("rule_action")), False
            while not done:
                obs, reward, terminated, truncated, info = env.step(policy(env, obs))
                record.add_step(reward, info)
                trace.record(env, info)
                if on_step is not None:
                    on_step(env, info)
                done = terminated or truncated
        record.yield_events = trace.yields()
        records.append(record)
    return records


#: The evaluation protocols: the authors' (actions sampled from the policy) and the argmax policy.
PROTOCOLS = {
    False: "sampled actions (the authors' protocol)",
    True: "deterministic (argmax) actions",
}


def protocol_label(deterministic: bool, masked: bool | None = None) -> str:
    """How an evaluation acted: sampled or argmax, with action masks or not (``masked``; None: not
    said), for tables and model cards (each evaluation reports both supervisor protocols,
    :data:`SUPERVISOR_PROTOCOLS`)."""
    label = PROTOCOLS[bool(deterministic)]
    if masked is not None:
        label += ", action masks" if masked else ", no action masks"
    return label + "; safety supervisor on and off"


def evaluation_records(
    policy: Policy,
    env_id: str,
    n_episodes: int,
    seed: int = 0,
    config: dict | None = None,
    on_step: StepHook | None = None,
    progress: str | None = None,
) -> list[EpisodeRecord]:
    """``n_episodes`` episodes with seeds ``seed, seed + 1, ...``, cycling through the density's AV
    counts (``on_step`` as in :func:`run_episodes`); with ``progress``, a progress bar of that name
    on stderr when it is a terminal."""
    counts = av_counts(env_id, config)
    envs = {n: make_scenario(env_id, {**(config or {}), "n_avs": n}) for n in counts}
    records = []
    bar = tqdm(range(n_episodes), desc=progress, unit="episode", disable=True if progress is None else None, leave=False)
    for episode in bar:
        env = envs[counts[episode % len(counts)]]
        records += run_episodes(env, policy, 1, seed=seed + episode, on_step=on_step)
    for env in envs.values():
        env.close()
    return records


def evaluate_on_density(
    policy: Policy, env_id: str, n_episodes: int, seed: int = 0, config: dict | None = None
) -> dict[str, float]:
    """Summary over ``n_episodes`` seeded episodes, cycling through the density's AV counts."""
    return summarize(evaluation_records(policy, env_id, n_episodes, seed, config))


def protocol_records(
    policy: Policy,
    env_id: str,
    n_episodes: int,
    seed: int = 0,
    config: dict | None = None,
    progress: bool = False,
    on_step: dict[str, StepHook] | None = None,
) -> dict[str, list[EpisodeRecord]]:
    """The same seeded episodes under each of :data:`SUPERVISOR_PROTOCOLS`: ``{"on": ..., "off": ...}``
    (``progress``: a progress bar per protocol; ``on_step``: a step hook per protocol)."""
    return {
        name: evaluation_records(
            policy,
            env_id,
            n_episodes,
            seed,
            with_supervisor(config, name),
            on_step=(on_step or {}).get(name),
            progress=f"supervisor {name}" if progress else None,
        )
        for name in SUPERVISOR_PROTOCOLS
    }


def evaluate_protocols(
    policy: Policy,
    env_id: str,
    n_episodes: int,
    seed: int = 0,
    config: dict | None = None,
    progress: bool = False,
    traffic: bool = False,
) -> dict[str, Any]:
    """The summary with the supervisor (the authors' protocol) at the top level, each episode's
    return in ``returns``, and the same under ``supervisor_off`` for the policy alone; with
    ``traffic``, each also has the traffic metrics (``traffic``) and every vehicle's trip record
    (``trips``; :mod:`~sb3_marl.evaluation.trips`)."""
    recorders = {name: TripRecorder() for name in SUPERVISOR_PROTOCOLS} if traffic else {}
    records = protocol_records(policy, env_id, n_episodes, seed, config, progress, on_step=dict(recorders))
    results = {name: protocol_result(records[name]) for name in SUPERVISOR_PROTOCOLS}
    for name, recorder in recorders.items():
        results[name].update(traffic=recorder.metrics(), trips=recorder.trips())
    return {**results["on"], "supervisor_off": results["off"]}


def protocol_result(records: list[EpisodeRecord]) -> dict[str, Any]:
    """:func:`summarize` plus each episode's return (``returns``)."""
    return {**summarize(records), "returns": [r.episode_return for r in records]}


def protocol_rows(label: dict[str, Any], result: dict[str, Any]) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """Two table rows of one :func:`evaluate_protocols` result: ``label`` plus ``supervisor`` on / off."""
    return [({**label, "supervisor": "on"}, result), ({**label, "supervisor": "off"}, result["supervisor_off"])]


__all__ = [
    "PROTOCOLS",
    "SUPERVISOR_PROTOCOLS",
    "Policy",
    "StepHook",
    "evaluate_on_density",
    "evaluate_protocols",
    "evaluation_records",
    "protocol_label",
    "protocol_records",
    "protocol_result",
    "protocol_rows",
    "run_episodes",
    "with_supervisor",
]
