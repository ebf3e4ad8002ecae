"""Training callbacks: driving metrics for TensorBoard, the paper's evaluation, atomic checkpoints.

All three plug into any SB3 algorithm trained on a :class:`~wrappers.ParameterSharingVecEnv`.
"""

from __future__ import annotations

import time
from collections import defaultdict, deque
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback

from sb3_marl.algos.common.policies import model_policy, non_finite_weights
from sb3_marl.common.files import read_evaluations, replaced_atomically
from sb3_marl.envs.lane_change_env import ACTIONS
from sb3_marl.evaluation import EpisodeRecord, protocol_records, summarize
from sb3_marl.evaluation.trips import TripRecorder
from wrappers.step_arrays import step_arrays_of

#: Per-AV-step driving samples of the step arrays, averaged (speed, headway) or spread (acceleration).
DRIVING_SAMPLES = ("speed", "headway", "acceleration")


class DivergedError(RuntimeError):
    """Training made a weight of the policy NaN or infinite; nothing is saved from that point."""


def check_finite(model: BaseAlgorithm) -> None:
    """A :class:`DivergedError` naming the first policy tensor of ``model`` that is NaN or infinite."""
    name = non_finite_weights(model.policy)
    if name is not None:
        raise DivergedError(
            f"training diverged at {model.num_timesteps} timesteps: the policy's weights {name} are NaN or "
            "infinite (try a smaller learning rate or loss weights)"
        )


def atomic_save(model: BaseAlgorithm, path: str | Path) -> Path:
    """``model.save(path)`` through a temporary file and a rename, so ``path`` is never half written;
    a model whose weights are not finite is never saved (:class:`DivergedError`)."""
    check_finite(model)
    path = Path(path).with_suffix(".zip")
    with replaced_atomically(path) as temporary:
        model.save(temporary)
    return path


class ProgressLinesCallback(BaseCallback):
    """``-P/--progress`` where the output is no terminal (a log file, a pipe): a line at each tenth
    of the budget (AV-steps done of the budget, elapsed and remaining wall time [s]) instead of a bar
    whose redraws fill the file with blank and overlong lines. Steps done before this call to
    ``learn`` (a resumed run, the DAgger warm start) count as done."""

    def __init__(self, lines: int = 10) -> None:
        super().__init__()
        self.lines = lines
        self.start_steps, self.target, self.printed, self.started = 0, 1, 0, 0.0

    def _on_training_start(self) -> None:
        self.start_steps = self.model.num_timesteps
        self.target = max(self.locals["total_timesteps"], 1)  # the budget's last AV-step (SB3's _setup_learn)
        self.printed, self.started = self._due(), time.perf_counter()

    def _due(self) -> int:
        return min(self.model.num_timesteps * self.lines // self.target, self.lines)

    def _on_step(self) -> bool:
        if self._due() > self.printed:
            self.printed = self._due()
            steps, elapsed = self.model.num_timesteps, time.perf_counter() - self.started
            left = elapsed * max(self.target - steps, 0) / max(steps - self.start_steps, 1)
            share = 100 * steps / self.target
            print(f"progress: {steps}/{self.target} AV-steps ({share:.0f} %), {elapsed:.0f} s, ~{left:.0f} s left", flush=True)
        return True


class FiniteWeightsCallback(BaseCallback):
    """Stops training with a :class:`DivergedError` when an update has left a policy weight NaN or
    infinite: checked as a rollout starts, at most once per ``every`` AV-steps (an off-policy
    learner's rollout is one VecEnv step, and the check reads every weight); every save checks
    too (:func:`atomic_save`), so no diverged model is ever written."""

    def __init__(self, every: int = 1000) -> None:
        super().__init__()
        self.every, self.checked_at = every, -every

    def _on_rollout_start(self) -> None:
        if self.model.num_timesteps - self.checked_at >= self.every:
            self.checked_at = self.model.num_timesteps
            check_finite(self.model)

    def _on_step(self) -> bool:
        return True


class AtomicCheckpointCallback(CheckpointCallback):
    """SB3's :class:`CheckpointCallback` (same ``rl_model_<steps>_steps.zip`` names) with atomic writes."""

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq == 0:
            path = atomic_save(self.model, self._checkpoint_path(extension="zip"))
            if self.verbose >= 2:
                print(f"Saving model checkpoint to {path}")
        return True


class StoreExecutedActions(BaseCallback):
    """Make the learner store the action the safety supervisor executed, not the policy's proposal.

    SB3 and sb3-contrib call the callback after each ``env.step`` and before the transition goes
    into the rollout / replay buffer; this callback overwrites, in place, the step's ``actions``
    with each slot's executed action (the VecEnv's ``step_arrays.executed_action``) and, for on-policy learners, the stored
    ``log_probs`` with the policy's log-probability of those actions (so the update stays A2C's:
    the probability ratio of the single step is 1). Slots whose action was not replaced are
    untouched. Used with ``stored_actions: executed`` in a zoo config.
    """

    def _on_step(self) -> bool:
        actions = self.locals["actions"]
        proposed = actions.reshape(-1)
        arrays = step_arrays_of(self.training_env)
        if arrays is None:
            return True
        executed = np.where(arrays.executed_action >= 0, arrays.executed_action, proposed)
        if np.array_equal(executed, proposed):
            return True
        proposed[:] = executed  # a view: the array the algorithm stores
        log_probs = self.locals.get("log_probs")  # an on-policy rollout's (a tensor, or our numpy rollout's array)
        if log_probs is not None:
            policy: Any = self.model.policy
            with th.no_grad():
                obs = policy.obs_to_tensor(self.model._last_obs)[0]  # the observations acted on
                distribution = policy.get_distribution(obs, action_masks=self.locals.get("action_masks"))
                replaced = distribution.log_prob(th.as_tensor(executed, device=policy.device))
            if isinstance(log_probs, np.ndarray):
                log_probs[:] = replaced.cpu().numpy()
            else:
                log_probs.copy_(replaced)
        return True


class DrivingMetricsCallback(BaseCallback):
    """Logs the scenario's driving metrics under ``rollout/`` at the end of every rollout.

    Per AV-step on the road, averaged over the rollouts between two logger dumps: ``speed_mean``
    [m/s], ``headway_mean`` [m], ``acceleration_std`` [m/s²] and each reward term (``reward_<term>``,
    unweighted). Over the last ``window`` finished scenario episodes: ``collision_rate``,
    ``success_rate`` (no crash), ``lane_changes_per_episode`` and ``episode_return`` (the paper's
    metric: sum over steps of the mean AV reward, before any reward scaling) and ``crash_step_mean``
    (the step at which crashed episodes ended). Learning diagnostics: ``supervisor_interventions``
    (share of AV-steps whose action the safety supervisor replaced) and ``action_share_<ACTION>``
    (share of each proposed meta-action).
    """

    def __init__(self, window: int = 100, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.episodes: deque[EpisodeRecord] = deque(maxlen=window)

    def _on_training_start(self) -> None:
        self._running: dict[int, EpisodeRecord] = defaultdict(EpisodeRecord)  # scenario copy -> its episode
        self._reset_rollout()

    def _reset_rollout(self) -> None:
        self._samples: dict[str, list[float]] = defaultdict(list)
        self._action_counts = np.zeros(len(ACTIONS), dtype=np.int64)

    def _on_step(self) -> bool:
        arrays = step_arrays_of(self.training_env)
        if arrays is None:
            return True
        for slot in range(len(arrays.copy)):
            self._running[int(arrays.copy[slot])].add_slot_step(arrays, slot)
        on_road = ~arrays.exited
        for key in DRIVING_SAMPLES:
            self._samples[key].extend(getattr(arrays, key)[on_road].tolist())
        for term, values in arrays.reward_terms.items():
            self._samples[f"reward_{term}"].extend(values[on_road].tolist())
        self._samples["supervisor_interventions"].extend(arrays.intervened[on_road].astype(float).tolist())
        proposed = arrays.proposed_action[on_road]
        self._action_counts += np.bincount(proposed[proposed >= 0], minlength=len(ACTIONS))
        for copy in sorted(set(arrays.copy[np.asarray(self.locals["dones"], dtype=bool)].tolist())):
            self.episodes.append(self._running.pop(copy))
        return True

    def _on_rollout_end(self) -> None:
        for key, values in self._samples.items():
            if key == "acceleration":
                self.logger.record_mean("rollout/acceleration_std", float(np.std(values)))
            elif key == "supervisor_interventions":
                self.logger.record_mean("rollout/supervisor_interventions", float(np.mean(values)))
            else:
                self.logger.record_mean(
                    f"rollout/{key}" if key.startswith("reward_") else f"rollout/{key}_mean", float(np.mean(values))
                )
        if self._action_counts.sum():
            for index, share in enumerate(self._action_counts / self._action_counts.sum()):
                self.logger.record_mean(f"rollout/action_share_{ACTIONS[index]}", float(share))
        self._reset_rollout()
        if self.episodes:
            episodes = list(self.episodes)
            self.logger.record("rollout/collision_rate", float(np.mean([e.crashed for e in episodes])))
            self.logger.record("rollout/success_rate", float(np.mean([not e.crashed for e in episodes])))
            self.logger.record("rollout/lane_changes_per_episode", float(np.mean([e.lane_changes for e in episodes])))
            self.logger.record("rollout/episode_return", float(np.mean([e.episode_return for e in episodes])))
            crash_steps = [e.length for e in episodes if e.crashed]
            if crash_steps:
                self.logger.record("rollout/crash_step_mean", float(np.mean(crash_steps)))


class ScenarioEvalCallback(BaseCallback):
    """Every ``eval_freq`` calls, plays ``n_eval_episodes`` seeded scenario episodes with the model.

    Unlike SB3's ``EvalCallback`` (one return per VecEnv slot, i.e. per AV) each evaluation episode
    scores the paper's metric: the sum over steps of the mean AV reward. The same seeds
    (``seed, seed + 1, ...``) are used at every evaluation, so the curve compares like with like.
    Each evaluation plays the episodes twice: with the safety supervisor (the authors' protocol)
    and without it (the policy alone). Results go to ``<log_path>/evaluations.npz`` in SB3's layout
    (``timesteps``, ``results``, ``ep_lengths``: supervisor on) plus one array per driving metric,
    and the same with the prefix ``supervisor_off_`` for the policy alone; to the logger under
    ``eval/`` and ``eval/supervisor_off/``; and the best model so far (supervisor on) to
    ``<best_model_save_path>/best_model.zip``. A run that ends before its first evaluation was due
    (a budget below ``eval_freq``, or one spent in a warm start that calls no callback) evaluates
    its final model once, so that ``best_model.zip`` and ``evaluations.npz`` exist. ``callback_after_eval`` is called
    after each evaluation (as in SB3's ``EvalCallback``; it sees this callback as ``parent``, with
    the latest summary in ``last_summary``; returning False stops training). With ``evaluate_at_end``, training
    that ends normally
    ends with an evaluation of the final model (unless one was just made at that step).
    """

    METRICS = (
        "collision_rate",
        "success_rate",
        "speed_mean",
        "headway_mean",
        "acceleration_std",
        "lane_changes_per_episode",
        "yields_per_episode",
        "intervention_rate",
        "rule_agreement",
    )
    #: Prefix of the policy-alone (supervisor off) arrays in ``evaluations.npz``.
    OFF = "supervisor_off_"

    def __init__(
        self,
        env_id: str,
        eval_freq: int,
        n_eval_episodes: int = 5,
        seed: int = 0,
        config: dict[str, Any] | None = None,
        log_path: str | Path | None = None,
        best_model_save_path: str | Path | None = None,
        deterministic: bool = False,
        callback_after_eval: BaseCallback | None = None,
        evaluate_at_end: bool = False,
        verbose: int = 1,
    ) -> None:
        super().__init__(verbose)
        self.evaluate_at_end = evaluate_at_end
        self.callback_after_eval = callback_after_eval
        if callback_after_eval is not None:
            callback_after_eval.parent = self
        self.last_summary: dict[str, Any] = {}
        self.env_id, self.config = env_id, config
        self.eval_freq, self.n_eval_episodes, self.seed = eval_freq, n_eval_episodes, seed
        self.log_path = Path(log_path) if log_path is not None else None
        self.best_model_save_path = Path(best_model_save_path) if best_model_save_path is not None else None
        self.deterministic = deterministic
        self.best_mean_reward = -np.inf
        self.evaluations: dict[str, list] = defaultdict(list)
        self.continue_training = True

    def _init_callback(self) -> None:
        if self.callback_after_eval is not None:
            self.callback_after_eval.init_callback(self.model)

    def _on_step(self) -> bool:
        if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
            self.evaluate()
        return self.continue_training

    def _on_training_end(self) -> None:
        timesteps = self.evaluations["timesteps"]
        if not timesteps and self.eval_freq > 0:
            if self.verbose >= 1:  # e.g. a budget that was all the DAgger warm start
                print(f"No evaluation was due during training: evaluating the final model ({self.num_timesteps} AV-steps)")
            self.evaluate()
        elif self.evaluate_at_end and (not timesteps or timesteps[-1] != self.num_timesteps):
            self.evaluate()

    def final_summary(self) -> dict[str, float]:
        """The latest evaluation's summary, also when it was loaded with :meth:`load_history`."""
        if not self.evaluations["results"]:
            raise ValueError("No evaluation has been made.")

        def latest(prefix: str) -> dict[str, float]:
            returns = np.asarray(self.evaluations[f"{prefix}results"][-1])
            return {
                "return_mean": float(returns.mean()),
                "return_std": float(returns.std()),
                **{
                    m: float(self.evaluations[f"{prefix}{m}"][-1])
                    for m in self.METRICS
                    if len(self.evaluations.get(f"{prefix}{m}", []))
                },
            }

        summary: dict[str, Any] = {"timesteps": int(self.evaluations["timesteps"][-1]), **latest("")}
        if len(self.evaluations.get(f"{self.OFF}results", [])):
            summary["supervisor_off"] = latest(self.OFF)
        return summary

    def load_history(self, path: str | Path, up_to_timesteps: int) -> None:
        """Continue the evaluation history of ``path`` (an ``evaluations.npz`` of this callback),
        keeping the evaluations at ``<= up_to_timesteps`` (those of a resumed checkpoint)."""
        log = read_evaluations(path)
        keep = log["timesteps"] <= up_to_timesteps
        self.evaluations = defaultdict(list, {key: list(values[keep]) for key, values in log.items()})
        if self.evaluations["results"]:
            self.best_mean_reward = max(float(np.mean(results)) for results in self.evaluations["results"])

    def evaluate(self) -> dict[str, Any]:
        """Run one evaluation now; returns its summary."""
        traffic = {name: TripRecorder() for name in ("on", "off")}  # TensorBoard's eval/traffic/ scalars
        policy = model_policy(self.model, self.deterministic)
        protocols = protocol_records(policy, self.env_id, self.n_eval_episodes, self.seed, self.config, on_step=dict(traffic))
        row: dict[str, Any] = {"timesteps": self.num_timesteps}
        summaries = {name: summarize(records) for name, records in protocols.items()}
        for name, prefix, folder in (("on", "", "eval/"), ("off", self.OFF, "eval/supervisor_off/")):
            records, protocol_summary = protocols[name], summaries[name]
            row[f"{prefix}results"] = [r.episode_return for r in records]
            row[f"{prefix}ep_lengths"] = [r.length for r in records]
            row.update({f"{prefix}{metric}": protocol_summary[metric] for metric in self.METRICS})
            for metric in ("return_mean", "return_std", "length_mean", *self.METRICS):
                key = {"return_mean": "mean_reward", "return_std": "std_reward", "length_mean": "mean_ep_length"}.get(
                    metric, metric
                )
                self.logger.record(folder + key, protocol_summary[metric])
            for metric, value in traffic[name].metrics().items():
                if np.isfinite(value):  # e.g. no HDV time loss where every vehicle is an AV
                    # TensorBoard's only: the console table (--verbose 2) cuts keys to 36 characters
                    self.logger.record(f"{folder}traffic/{metric}", value, exclude="stdout")
        off = summaries["off"]
        summary: dict[str, Any] = {**summaries["on"], "supervisor_off": off}
        for key, value in row.items():
            self.evaluations[key].append(value)
        if self.log_path is not None:
            with replaced_atomically(self.log_path / "evaluations.npz") as temporary:
                np.savez(temporary, **{key: np.array(values) for key, values in self.evaluations.items()})  # type: ignore[arg-type]

        if self.verbose >= 1:
            print(
                f"Eval num_timesteps={self.num_timesteps}, episode_return={summary['return_mean']:.2f} "
                f"+/- {summary['return_std']:.2f}, collision_rate={summary['collision_rate']:.2f}; supervisor off: "
                f"episode_return={off['return_mean']:.2f}, collision_rate={off['collision_rate']:.2f}"
            )
        if summary["return_mean"] > self.best_mean_reward:
            self.best_mean_reward = summary["return_mean"]
            if self.best_model_save_path is not None:
                atomic_save(self.model, self.best_model_save_path / "best_model.zip")
                if self.verbose >= 1:
                    print("New best mean reward!")
        self.logger.dump(self.num_timesteps)
        self.last_summary = summary
        if self.callback_after_eval is not None:
            self.continue_training = self.callback_after_eval.on_step()
        return summary


__all__ = [
    "AtomicCheckpointCallback",
    "DivergedError",
    "DrivingMetricsCallback",
    "FiniteWeightsCallback",
    "ScenarioEvalCallback",
    "atomic_save",
]
