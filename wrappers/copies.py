"""Scenario copies and where they run: :class:`CopyRunner` steps one copy with SB3's VecEnv
conventions; :class:`~wrappers.ParameterSharingVecEnv` calls its runners directly on the ``dummy``
backend, and through :class:`CopyGroups` of :class:`WorkerCopies`, a group in each worker process,
on the ``subproc`` backend."""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import signal
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper

from sb3_marl.envs.reward import apply_reward_mode
from wrappers.step_arrays import Ending, copy_arrays


class CopyRunner:
    """One scenario copy with SB3's VecEnv conventions: auto-reset, ``terminal_observation`` and
    ``TimeLimit.truncated`` as SB3's ``DummyVecEnv`` sets them (without its per-step deep copy of
    the info, which cost more than 5 % of a step). It also applies the reward mode and splits the
    info per AV, so that worker processes do that work in parallel.

    With ``supervisor_dropout`` p > 0 (and the scenario's safety supervisor on) each episode runs
    without the supervisor with probability p, drawn at its reset from a generator seeded by the
    copy's seeded reset (same seed, same episodes; the scenario's
    :meth:`~sb3_marl.envs.lane_change_env.LaneChangeEnv.set_supervisor_dropout`): training meets its
    own mistakes with their crash cost, while most episodes keep the supervisor's safe exploration.
    """

    def __init__(self, factory: Callable[[], gym.Env], copy: int, reward_mode: str, supervisor_dropout: float = 0.0) -> None:
        self.env = factory()
        self.copy = copy
        self.reward_mode = reward_mode
        if supervisor_dropout:
            scenario = self.env.unwrapped
            if not hasattr(scenario, "set_supervisor_dropout"):
                raise ValueError(
                    f"Invalid supervisor_dropout={supervisor_dropout}: copy {copy} ({type(scenario).__name__}) is not "
                    "a scenario env with a safety supervisor (expected 0)."
                )
            scenario.set_supervisor_dropout(supervisor_dropout, copy)

    def spaces(self) -> tuple[spaces.Space, spaces.Space]:
        return self.env.observation_space, self.env.action_space

    def reset(self, seed: int | None, options: dict[str, Any]) -> tuple[np.ndarray, dict[str, Any]]:
        """Observations (n_avs, ...) and the per-AV step arrays (:func:`copy_arrays`)."""
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
        obs, info = self.env.reset()
        return obs, copy_arrays(info)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool, dict[str, Any], Ending | None]:
        """Step with one action per AV: observations (the new episode's when done), rewards in
        the reward mode, done, the per-AV step arrays (:func:`copy_arrays`) and, when
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


def run_calls(runners: Sequence[CopyRunner], calls: list[Call]) -> list[Any]:
    """The results of ``calls`` on ``runners``, in order."""
    return [getattr(runners[index], method)(*args) for index, method, args in calls]


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
            remote.send(("ok", run_calls(runners, calls)))
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


class CopyGroups:
    """The copies spread round-robin over ``n_workers`` worker processes; calls go to every group at once.

    :param runners: a factory of each copy's :class:`CopyRunner`, in copy order
    :param start_method: multiprocessing start method of the workers (default: ``forkserver``
        where available, as SB3's ``SubprocVecEnv``)
    :param timeout: seconds a worker may take to answer one call
    """

    def __init__(
        self,
        runners: Sequence[Callable[[], CopyRunner]],
        n_workers: int,
        start_method: str | None = None,
        timeout: float = 120.0,
    ) -> None:
        n_copies = len(runners)
        #: copy k runs in group placement[k][0] at index placement[k][1]
        self.placement = [(k % n_workers, k // n_workers) for k in range(n_copies)]
        self.group_copies = [list(range(g, n_copies, n_workers)) for g in range(n_workers)]
        if start_method is None:
            start_method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        context = mp.get_context(start_method)
        self.groups = [WorkerCopies([runners[k] for k in copies], context, timeout) for copies in self.group_copies]

    def submit(self, calls: dict[int, tuple[str, tuple]]) -> list[tuple[int, list[int]]]:
        """Send ``{copy: (method, args)}`` to the groups; returns what :meth:`collect` needs."""
        pending = []
        for group, copies in enumerate(self.group_copies):
            mine = [k for k in copies if k in calls]
            if mine:
                self._guard(group, self.groups[group].submit, [(self.placement[k][1], *calls[k]) for k in mine])
                pending.append((group, mine))
        return pending

    def collect(self, pending: list[tuple[int, list[int]]]) -> dict[int, Any]:
        """``{copy: result}`` of the calls :meth:`submit` sent."""
        results: dict[int, Any] = {}
        for group, copies in pending:
            results.update(zip(copies, self._guard(group, self.groups[group].collect)))
        return results

    def _guard(self, group: int, method: Callable, *args: Any) -> Any:
        """A dead worker process becomes an error naming its copies, never a hang."""
        try:
            return method(*args)
        except TimeoutError as error:
            raise TimeoutError(f"{error} It hosts scenario copies {self.group_copies[group]}.") from None
        except (EOFError, BrokenPipeError, ConnectionResetError) as error:
            code = self.groups[group].process.exitcode
            raise RuntimeError(
                f"Worker process {group} of scenario copies {self.group_copies[group]} died ({_exit_reason(code)})."
            ) from error

    def close(self) -> None:
        for group in self.groups:
            with contextlib.suppress(EOFError, BrokenPipeError, ConnectionResetError):
                group.close()  # a dead worker has nothing left to close


def _exit_reason(code: int | None) -> str:
    """How a worker process ended, from its exit code (negative: the signal that killed it)."""
    if code is None:
        return "no exit code yet"
    if code < 0:
        return f"killed by {signal.Signals(-code).name}: out of memory, or stopped from outside"
    return f"exit code {code}; a Python error in it printed its traceback above"


def per_agent_spaces(copy_spaces: dict[int, tuple]) -> tuple[spaces.Box, spaces.Discrete, list[int]]:
    """Per-slot spaces and AV counts of the copies' ``{copy: (observation space, action space)}``;
    a clear error for envs that are not multi-agent scenarios."""
    n_avs: list[int] = []
    obs_space: spaces.Box | None = None
    action_space: spaces.Discrete | None = None
    for k, (copy_obs, copy_actions) in sorted(copy_spaces.items()):
        if not (
            isinstance(copy_actions, spaces.MultiDiscrete)
            and isinstance(copy_obs, spaces.Box)
            and copy_obs.shape[:1] == copy_actions.shape
            and len(set(copy_actions.nvec.tolist())) == 1
        ):
            raise ValueError(
                f"Copy {k} is not a multi-agent scenario env: expected a MultiDiscrete action space "
                f"(one action per AV) and a Box observation space with one row per AV, got "
                f"{copy_actions} and {copy_obs}."
            )
        agent_obs = spaces.Box(copy_obs.low[0], copy_obs.high[0], dtype=copy_obs.dtype)  # type: ignore[arg-type]
        agent_actions: spaces.Discrete = spaces.Discrete(int(copy_actions.nvec[0]))
        if obs_space is not None and (agent_obs != obs_space or agent_actions != action_space):
            raise ValueError(
                f"Copy {k} has per-AV spaces {agent_obs}, {agent_actions}, unlike copy 0's "
                f"{obs_space}, {action_space}: all copies must share one per-AV observation and action space."
            )
        obs_space, action_space = agent_obs, agent_actions
        n_avs.append(int(copy_actions.shape[0]))
    assert obs_space is not None and action_space is not None, "no scenario copy"
    return obs_space, action_space, n_avs
