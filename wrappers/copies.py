"""Scenario copies and where they run: :class:`CopyRunner` steps one copy with SB3's VecEnv
conventions; :class:`LocalCopies` runs a group of them in this process, :class:`WorkerCopies` in a
worker process (the ``subproc`` backend of :class:`~wrappers.ParameterSharingVecEnv`)."""

from __future__ import annotations

import contextlib
import signal
import traceback
from collections.abc import Callable, Iterator, Sequence
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper

from sb3_marl.envs.config import with_supervisor
from sb3_marl.envs.reward import REWARD_MODES, apply_reward_mode, mode_rewards

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


#: Slot-info entries read as Python numbers (the others are the arrays' numpy values).
FLOAT_ENTRIES, INT_ENTRIES = ("reward", "global_reward"), ("copy", "agent")


def copy_arrays(info: dict[str, Any]) -> dict[str, Any]:
    """What the slot infos of a copy's AVs carry, as per-AV arrays (n_avs, ...): the entries of
    :data:`PER_AGENT_INFO`, ``reward`` (the AV's own), ``global_reward`` (the copy's mean) and
    ``reward_terms`` (a dict of arrays)."""
    own = np.asarray(info["rewards"], dtype=np.float64)
    arrays: dict[str, Any] = {key: np.asarray(info[key]) for key in PER_AGENT_INFO if key in info}
    arrays["reward"] = own
    arrays["global_reward"] = mode_rewards(own, np.ones((own.size, own.size), dtype=np.bool_), REWARD_MODES.index("global"))
    arrays["reward_terms"] = {name: np.asarray(values) for name, values in info.get("reward_terms", {}).items()}
    return arrays


def join_arrays(parts: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The per-slot arrays of several copies' :func:`copy_arrays`, copy after copy (the entries all share)."""
    keys = [key for key in parts[0] if key != "reward_terms" and all(key in part for part in parts)]
    joined: dict[str, Any] = {key: np.concatenate([part[key] for part in parts]) for key in keys}
    terms = [part["reward_terms"] for part in parts]
    shared = [name for name in terms[0] if all(name in t for t in terms)]
    joined["reward_terms"] = {name: np.concatenate([t[name] for t in terms]) for name in shared}
    return joined


class SlotInfo(dict):
    """One slot's info (see :class:`~wrappers.ParameterSharingVecEnv`), a dict: its row of the
    step's per-slot arrays, read when asked, and entries of its own (``terminal_observation``,
    ``episode``, what wrappers add), stored as a dict's. Building one costs no more than an empty
    dict; a consumer that wants every slot's value reads :attr:`arrays` whole."""

    __slots__ = ("arrays", "deleted", "slot")

    def __init__(self, arrays: dict[str, Any], slot: int) -> None:
        super().__init__()
        self.arrays, self.slot = arrays, slot
        self.deleted: tuple[str, ...] = ()

    def _row(self, key: str) -> Any:
        if key == "reward_terms":
            return {name: float(values[self.slot]) for name, values in self.arrays[key].items()}
        value = self.arrays[key][self.slot]
        return float(value) if key in FLOAT_ENTRIES else int(value) if key in INT_ENTRIES else value

    def _shared(self, key: object) -> bool:
        return key in self.arrays and not dict.__contains__(self, key) and key not in self.deleted

    def __getitem__(self, key: str) -> Any:
        if dict.__contains__(self, key):
            return dict.__getitem__(self, key)
        if key in self.deleted:
            raise KeyError(key)
        return self._row(key)

    def get(self, key: str, default: Any = None) -> Any:
        if key not in self:
            return default
        return self[key]

    def __contains__(self, key: object) -> bool:
        return dict.__contains__(self, key) or self._shared(key)

    def __delitem__(self, key: str) -> None:
        if dict.__contains__(self, key):
            dict.__delitem__(self, key)
        elif self._shared(key):
            self.deleted = (*self.deleted, key)
        else:
            raise KeyError(key)

    def __iter__(self) -> Iterator[str]:
        yield from (key for key in self.arrays if self._shared(key))
        yield from dict.__iter__(self)

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def keys(self) -> list[str]:  # type: ignore[override]
        return list(self)

    def items(self) -> list[tuple[str, Any]]:  # type: ignore[override]
        return [(key, self[key]) for key in self]

    def values(self) -> list[Any]:  # type: ignore[override]
        return [self[key] for key in self]

    def copy(self) -> dict[str, Any]:
        """A plain dict of every entry (SB3's ``VecMonitor`` copies infos)."""
        return dict(self.items())

    def __eq__(self, other: object) -> bool:
        return isinstance(other, dict) and dict(self.items()) == dict(other.items())

    __hash__ = None

    def __repr__(self) -> str:
        return f"SlotInfo({dict(self.items())!r})"


def slot_infos(arrays: dict[str, Any]) -> list[SlotInfo]:
    """One :class:`SlotInfo` per slot of the per-slot ``arrays``."""
    return [SlotInfo(arrays, slot) for slot in range(len(arrays["reward"]))]


class Ending(NamedTuple):
    """How a copy's episode ended: its last observations (n_avs, ...), whether by a time limit or
    the road's end (SB3's ``TimeLimit.truncated``; a crash is a termination), and the slot-info
    arrays of the new episode's first observations."""

    terminal_observation: np.ndarray
    time_limit: bool
    reset_arrays: dict[str, Any]


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

    def reset(self, seed: int | None, options: dict[str, Any]) -> tuple[np.ndarray, dict[str, Any]]:
        """Observations (n_avs, ...) and the per-AV arrays of the slot infos (:func:`copy_arrays`)."""
        options = self._episode_options(seed, options)
        obs, info = self.env.reset(seed=seed, **({"options": options} if options else {}))
        missing = [key for key in ("rewards", "neighbours") if key not in info]
        if missing:
            raise ValueError(
                f"Copy {self.copy} is not a multi-agent scenario env: its info lacks {missing} "
                "(per-AV rewards and the local reward's neighbour sets)."
            )
        return obs, copy_arrays(info)

    def restart(self) -> tuple[np.ndarray, dict[str, Any]]:
        """:meth:`reset` after an episode ended (no seed: the copy's generator goes on)."""
        obs, info = self.env.reset(options=self._episode_options(None) or None)
        return obs, copy_arrays(info)

    def begin_episode(self) -> None:
        """:meth:`restart` without the first observation (the scenario's ``begin``: a batch observes)."""
        self.env.unwrapped.begin(options=self._episode_options(None) or None)  # type: ignore[attr-defined]

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool, dict[str, Any], Ending | None]:
        """Step with one action per AV: observations (the new episode's when done), rewards in
        the reward mode, done, the per-AV arrays of the slot infos (:func:`copy_arrays`) and, when
        done, how the episode ended."""
        obs, _, terminated, truncated, info = self.env.step(actions)
        ending = None
        if terminated or truncated:
            terminal = obs
            obs, reset_arrays = self.restart()
            ending = Ending(terminal, bool(truncated and not terminated), reset_arrays)
        return obs, apply_reward_mode(info, self.reward_mode), ending is not None, copy_arrays(info), ending

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
