"""Scenario copies and where they run: :class:`CopyRunner` steps one copy with SB3's VecEnv
conventions; :class:`LocalCopies` runs a group of them in this process, :class:`WorkerCopies` in a
worker process (the ``subproc`` backend of :class:`~wrappers.ParameterSharingVecEnv`)."""

from __future__ import annotations

import contextlib
import signal
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper

from sb3_marl.envs.config import with_supervisor
from sb3_marl.envs.reward import apply_reward_mode

#: Per-AV arrays of the scenario's info that each slot's info carries as scalars.
PER_AGENT_INFO = (
    "speed",
    "headway",
    "acceleration",
    "lane_change",
    "crashed",
    "exited",
    "action_mask",
    "proposed_action",
    "executed_action",
    "intervened",
    "rule_action",
)


def split_info(info: dict[str, Any], copy: int) -> list[dict[str, Any]]:
    """Each AV's share of its copy's info (see :class:`ParameterSharingVecEnv`)."""
    own = np.asarray(info["rewards"])
    global_reward = float(own.mean())
    terms = info.get("reward_terms", {})
    slot_infos = []
    for agent in range(own.size):
        slot_info = {key: info[key][agent] for key in PER_AGENT_INFO if key in info}
        slot_info.update(
            copy=copy,
            agent=agent,
            reward=float(own[agent]),
            global_reward=global_reward,
            reward_terms={name: float(values[agent]) for name, values in terms.items()},
        )
        if "terminal_observation" in info:
            slot_info["terminal_observation"] = info["terminal_observation"][agent]
            slot_info["TimeLimit.truncated"] = bool(info["TimeLimit.truncated"])
        slot_infos.append(slot_info)
    return slot_infos


class CopyRunner:
    """One scenario copy with SB3's VecEnv conventions: auto-reset, ``terminal_observation`` and
    ``TimeLimit.truncated`` as SB3's ``DummyVecEnv`` sets them (without its per-step deep copy of
    the info, which cost more than 5 % of a step). It also applies the reward mode and splits the
    info per AV, so that worker processes do that work in parallel.

    With ``supervisor_dropout`` p > 0 (and the scenario's safety supervisor on) each episode runs
    without the supervisor with probability p, drawn at its reset from a generator seeded by the
    copy's seeded reset (same seed, same episodes): training meets its own mistakes with their
    crash cost, while most episodes keep the supervisor's safe exploration.
    """

    def __init__(self, factory: Callable[[], gym.Env], copy: int, reward_mode: str, supervisor_dropout: float = 0.0) -> None:
        self.env = factory()
        self.copy = copy
        self.reward_mode = reward_mode
        self.supervisor_dropout = supervisor_dropout
        # whether the dropout switches the scenario's safety supervisor (configured on: a scenario env)
        config = getattr(self.env.unwrapped, "config", {})
        self._supervised = bool(config.get("safety_supervisor", False)) if supervisor_dropout else False
        self._dropout_rng = np.random.default_rng()

    def _episode_options(self, seed: int | None, options: dict[str, Any] | None = None) -> dict[str, Any]:
        """The reset options of the episode about to start: with ``supervisor_dropout``, the
        scenario's config for it with the supervisor drawn on or off (highway-env's
        ``options={"config": ...}``, written by :func:`~sb3_marl.envs.config.with_supervisor`)."""
        options = dict(options or {})
        if self._supervised:
            if seed is not None:
                self._dropout_rng = np.random.default_rng([seed, self.copy])
            on = bool(self._dropout_rng.random() >= self.supervisor_dropout)
            options["config"] = with_supervisor(options.get("config"), on)
        return options

    def spaces(self) -> tuple[spaces.Space, spaces.Space]:
        return self.env.observation_space, self.env.action_space

    def reset(self, seed: int | None, options: dict[str, Any]) -> tuple[np.ndarray, list[dict[str, Any]]]:
        """Observations (n_avs, ...) and per-AV reset infos."""
        options = self._episode_options(seed, options)
        obs, info = self.env.reset(seed=seed, **({"options": options} if options else {}))
        missing = [key for key in ("rewards", "neighbours") if key not in info]
        if missing:
            raise ValueError(
                f"Copy {self.copy} is not a multi-agent scenario env: its info lacks {missing} "
                "(per-AV rewards and the local reward's neighbour sets)."
            )
        return obs, split_info(info, self.copy)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool, list[dict], list[dict] | None]:
        """Step with one action per AV: observations, rewards in the reward mode, done, per-AV
        infos, and per-AV reset infos of the new episode when done (else None)."""
        obs, _, terminated, truncated, info = self.env.step(actions)
        done = bool(terminated or truncated)
        reset_infos = None
        if done:
            info["terminal_observation"] = obs
            info["TimeLimit.truncated"] = bool(truncated and not terminated)
            obs, reset_info = self.env.reset(options=self._episode_options(None) or None)
            reset_infos = split_info(reset_info, self.copy)
        return obs, apply_reward_mode(info, self.reward_mode), done, split_info(info, self.copy), reset_infos

    def get_attr(self, name: str) -> Any:
        return self.env.get_wrapper_attr(name)

    def set_attr(self, name: str, value: Any) -> None:
        setattr(self.env, name, value)  # on the outer wrapper, as SB3's VecEnvs do

    def env_method(self, name: str, args: tuple, kwargs: dict[str, Any]) -> Any:
        return self.env.get_wrapper_attr(name)(*args, **kwargs)

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper]) -> bool:
        return is_wrapped(self.env, wrapper_class)

    def get_image(self) -> Any:
        return self.env.render()

    def close(self) -> None:
        self.env.close()


Call = tuple[int, str, tuple]  # (copy index within its group, CopyRunner method, arguments)


def _run_calls(runners: list[CopyRunner], calls: list[Call]) -> list[Any]:
    return [getattr(runners[index], method)(*args) for index, method, args in calls]


class LocalCopies:
    """Copies stepped one after the other in this process."""

    def __init__(self, runners: Sequence[Callable[[], CopyRunner]]) -> None:
        self.runners = [make_runner() for make_runner in runners]
        self._results: list[Any] = []

    def submit(self, calls: list[Call]) -> None:
        self._results = _run_calls(self.runners, calls)

    def collect(self) -> list[Any]:
        return self._results

    def close(self) -> None:
        for runner in self.runners:
            runner.close()


def _worker(remote: Any, parent_remote: Any, factories: CloudpickleWrapper) -> None:
    """Worker process: host a group of copies and run the calls the main process sends.

    Ctrl-C is left to the main process, which stops training and then closes the workers."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent_remote.close()
    runners: list[CopyRunner] = [make_runner() for make_runner in factories.var]
    while True:
        try:
            calls = remote.recv()
        except (EOFError, KeyboardInterrupt):
            break
        if calls is None:
            for runner in runners:
                runner.close()
            remote.close()
            break
        try:
            remote.send(("ok", _run_calls(runners, calls)))
        except Exception as error:  # forwarded to the main process, which re-raises it
            remote.send(("error", (error, traceback.format_exc())))


class WorkerCopies:
    """A group of copies in one worker process, stepped in parallel with the other groups.

    :param timeout: seconds to wait for the worker's answer before giving up with an error (a
        stopped or hung worker must not block training forever)
    """

    def __init__(self, runners: Sequence[Callable[[], CopyRunner]], context: Any, timeout: float = 120.0) -> None:
        self.timeout = timeout
        self.started = False
        self.remote, work_remote = context.Pipe()
        self.process = context.Process(
            target=_worker, args=(work_remote, self.remote, CloudpickleWrapper(runners)), daemon=True
        )
        self.process.start()
        work_remote.close()

    def submit(self, calls: list[Call]) -> None:
        self.remote.send(calls)

    def collect(self) -> list[Any]:
        # the first answer waits for the worker's start-up (imports, building the copies) too
        if not self.remote.poll(self.timeout if self.started else None):
            raise TimeoutError(
                f"Worker process {self.process.pid} did not answer within {self.timeout} s "
                f"({'alive but not responding: stopped or hung' if self.process.is_alive() else 'dead'})."
            )
        status, payload = self.remote.recv()
        self.started = True
        if status == "error":
            error, remote_traceback = payload
            raise error from RuntimeError(f"in the worker process:\n{remote_traceback}")
        return payload

    def close(self) -> None:
        if self.process.is_alive():
            with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                self.remote.send(None)
        self.process.join(timeout=5)
        if self.process.is_alive():
            self.process.terminate()
        self.remote.close()
