"""One benchmark trial as a Ray Tune function trainable, trained with the ``train`` machinery.

The trial's folder ``<log folder>/trials/<trial id>/`` is an rl-zoo log folder: the run is
``<algo>/<env name>_1/`` (model zip, ``evaluations.npz``, ``monitor.csv``, ``<env name>/config.yml``)
and TensorBoard logs are in ``tensorboard/``, so ``sb3-marl evaluate/plot -f <trial folder>`` work
on it. Beside them:

- ``checkpoint/`` (replaced atomically after every evaluation): ``model.zip``, the replay buffer of
  off-policy learners (``replay_buffer.npz``: arrays, read back as data, so a grid folder from
  someone else resumes without running anything of theirs), ``evaluations.npz`` and ``state.json``;
  the same files are reported to Ray Tune as the trial's checkpoint, from which Ray restarts a
  trial whose worker died;
- ``trial.json``: the trial and its settings, with one entry per attempt (start, host, pid, and
  ``wall_time_s``: its training time up to its latest checkpoint [s]);
- ``result.json`` (written last): the last periodic evaluation and the paper's final evaluation
  of the trained model (``paper_evaluation``, :data:`FINAL_EVAL_EPISODES` seeded episodes).
  A trial with it, whose files all read back (:mod:`~sb3_marl.benchmark.repair`), is finished and
  skipped when the benchmark runs again; one without it continues from ``checkpoint/``.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import socket
import tempfile
import time
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from sb3_marl.benchmark.grid import TrialSpec
from sb3_marl.benchmark.storage import GridStorage
from sb3_marl.benchmark.trial_files import (
    CHECKPOINT,
    FINAL_EVAL_EPISODES,
    PREVIOUS_CHECKPOINT,
    RESULT,
    RUN_ID,
    SETTINGS,
    TRIAL,
    read_trial_info,
    total_wall_time,
    trial_folder,
)
from sb3_marl.common.compiled import compiling
from sb3_marl.common.files import (
    REPLAY_BUFFER_FILE,
    read_json_object,
    replaced_atomically,
    write_replay_buffer,
    write_text,
)


def write_json(path: Path, data: dict[str, Any]) -> None:
    write_text(path, json.dumps(data, indent=2) + "\n")


class CheckpointAndReport(BaseCallback):
    """After each evaluation (as ``callback_after_eval`` of the ScenarioEvalCallback): replace
    ``checkpoint/`` with the model and the evaluations so far, then report the evaluation to Ray
    Tune with that checkpoint; with a grid ``storage``, upload the checkpoint and the trial folder
    there instead of handing the checkpoint to Ray."""

    def __init__(self, folder: Path, spec: TrialSpec, storage: GridStorage | None = None) -> None:
        super().__init__()
        self.folder, self.spec, self.storage = folder, spec, storage
        self.started = time.perf_counter()  # when this attempt's training began [s, perf_counter]

    def _on_step(self) -> bool:
        from ray import tune

        evaluation: Any = self.parent  # the ScenarioEvalCallback that calls this one after each evaluation
        checkpoint = write_checkpoint(self.model, self.folder, evaluation.log_path / "evaluations.npz")
        record_wall_time(self.folder, time.perf_counter() - self.started)
        metrics = trial_metrics(self.spec, self.model.num_timesteps, evaluation.last_summary)
        if self.storage is not None:  # the checkpoint, then the trial folder, to the grid's storage
            self.storage.upload_checkpoint(checkpoint, self.spec.trial_id, int(self.model.num_timesteps))
            self.storage.upload_trial(self.folder)
            tune.report(metrics)
        else:
            tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(str(checkpoint)))
        return True


def write_checkpoint(model: Any, folder: Path, evaluations: Path) -> Path:
    """``<folder>/checkpoint/`` with the model, its replay buffer, a copy of ``evaluations`` (the
    ``evaluations.npz`` so far) and the step count, written beside and renamed into place (a crash
    leaves the previous one whole)."""
    final, staging = folder / CHECKPOINT, folder / f".{CHECKPOINT}.partial-{os.getpid()}"  # one per process
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    model.save(staging / "model.zip")
    if getattr(model, "replay_buffer", None) is not None:
        write_replay_buffer(model.replay_buffer, staging / REPLAY_BUFFER_FILE)
    shutil.copy2(evaluations, staging / "evaluations.npz")
    (staging / "state.json").write_text(json.dumps({"num_timesteps": int(model.num_timesteps)}))
    previous = folder / PREVIOUS_CHECKPOINT
    shutil.rmtree(previous, ignore_errors=True)
    if final.exists():
        final.rename(previous)
    staging.rename(final)
    shutil.rmtree(previous, ignore_errors=True)
    return final


def record_wall_time(folder: Path, seconds: float) -> dict[str, Any]:
    """Set the current (last) attempt's ``wall_time_s`` in ``<folder>/trial.json`` to ``seconds``; the file's data."""
    info = read_trial_info(folder / TRIAL)
    info["attempts"][-1]["wall_time_s"] = round(seconds, 1)
    write_json(folder / TRIAL, info)
    return info


def trial_metrics(spec: TrialSpec, num_timesteps: int, summary: dict[str, float]) -> dict[str, Any]:
    """What the trial reports to Ray Tune: progress in AV-steps and env steps, and the evaluation."""
    return {
        "timesteps": int(num_timesteps),
        "env_steps": int(spec.env_steps(num_timesteps)),
        **{f"eval_{k}": v for k, v in summary.items()},
    }


def run_trial(config: dict[str, Any]) -> None:
    """Train and evaluate one trial (Ray Tune function trainable); a curriculum trial
    (:attr:`TrialSpec.starts_from`) starts from the final weights of the trial before it.

    ``config``: ``spec`` (a :class:`TrialSpec` as a dict), ``log_folder`` (absolute), ``budget``
    (fraction of 1M env steps), ``eval_every_episodes``, ``eval_episodes``, and ``storage`` (a URI
    or None). Resumes from Ray's checkpoint when Ray restarts the trial, else from ``checkpoint/``
    of an earlier run of the benchmark. With ``storage``, the trial works in a node-local folder
    that it fills from the storage and uploads to it (:mod:`~sb3_marl.benchmark.storage`).
    """
    import torch
    from ray import tune

    from sb3_marl.runs.callbacks import ScenarioEvalCallback
    from sb3_marl.runs.experiment import MARLExperimentManager
    from sb3_marl.runs.folders import RunSpec

    torch.set_num_threads(1)  # one core per trial: Ray schedules trials by CPU
    spec = TrialSpec(**config["spec"])
    storage = GridStorage(config["storage"]) if config.get("storage") else None
    log_folder = Path(tempfile.mkdtemp(prefix=f"sb3-marl-{spec.trial_id}-")) if storage else Path(config["log_folder"])
    folder = trial_folder(log_folder, spec)
    checkpoint = folder / CHECKPOINT
    if storage is not None:  # this node's copy of the trial (and of the model it starts from)
        storage.download_trials(log_folder, [spec.trial_id, *([spec.starts_from.trial_id] if spec.starts_from else [])])
        storage.download_checkpoint(spec.trial_id, checkpoint)
    folder.mkdir(parents=True, exist_ok=True)
    for debris in folder.glob(f".{CHECKPOINT}.partial-*"):  # staged by a killed attempt (one attempt runs at a time)
        shutil.rmtree(debris, ignore_errors=True)
    resumed_at = _restore_checkpoint(folder, tune.get_checkpoint())
    _record_attempt(folder, spec, config, resumed_at)
    run = RunSpec(
        algo=spec.algo,
        env=spec.env_id,
        log_folder=str(folder),
        seed=spec.seed,
        n_timesteps=spec.n_timesteps(config["budget"]),
        eval_freq=spec.eval_freq(config["eval_every_episodes"]),
        eval_episodes=config["eval_episodes"],
        hyperparams=spec.hyperparams,
        trained_agent=str(checkpoint / "model.zip") if resumed_at else "",
        tensorboard_log=str(folder / "tensorboard"),
        verbose=0,
        device="cpu",
        run_id=RUN_ID,
        monitor_file="monitor.csv" if not resumed_at else f"resumed_at_{resumed_at}.monitor.csv",
        evaluate_at_end=True,
    )
    reporter = CheckpointAndReport(folder, spec, storage)
    manager = MARLExperimentManager(run, callback_after_eval=reporter)
    model, _ = manager.setup_experiment()  # type: ignore[misc]
    if spec.starts_from is not None and not resumed_at:  # a curriculum: the easier density's final weights
        model.set_parameters(str(start_model(log_folder, spec.starts_from)), device="cpu")
    evaluation = next(c for c in manager.callbacks if isinstance(c, ScenarioEvalCallback))
    if resumed_at:  # the run's evaluations are the checkpoint's until the next one (none, resumed at its budget)
        evaluation.load_history(checkpoint / "evaluations.npz", resumed_at)
        assert evaluation.log_path is not None  # the experiment manager gives its evaluation the run folder
        with replaced_atomically(evaluation.log_path / "evaluations.npz") as temporary:
            shutil.copyfile(checkpoint / "evaluations.npz", temporary)
    reporter.started = time.perf_counter()
    with compiling() as compile_time:
        manager.learn(model)
    if compile_time.seconds >= 1:  # the trial's log (Ray's worker output): a node's first trial compiles
        print(f"trial {spec.trial_id}: {compile_time.seconds:.1f} s of its training compiled the road kernel (first run here)")
    if manager.interrupted:
        raise KeyboardInterrupt(f"trial {spec.trial_id} interrupted")
    manager.save_trained_model(model)
    info = record_wall_time(folder, time.perf_counter() - reporter.started)
    result = {
        **info,
        "num_timesteps": int(model.num_timesteps),
        "env_steps": int(spec.env_steps(model.num_timesteps)),
        "final_evaluation": evaluation.final_summary(),
        "final_returns": [float(r) for r in evaluation.evaluations["results"][-1]],
        "paper_evaluation": paper_evaluation(model, spec.env_id, manager.scenario.get("env_config")),
        "wall_time_s": total_wall_time(info["attempts"]),  # every attempt's
        "machine": f"{platform.node()} ({os.cpu_count()} cores)",
    }
    if storage is not None:  # the transfers so far (all but the last upload): the storage's cost
        result["storage"] = {"uri": storage.uri, "sync_s": round(storage.sync_s, 3), "bytes": storage.bytes}
    write_json(folder / RESULT, result)
    if storage is not None:
        storage.upload_trial(folder, last=RESULT)
        shutil.rmtree(log_folder, ignore_errors=True)


def start_model(log_folder: str | Path, start: TrialSpec) -> Path:
    """The final model zip of the finished trial ``start`` (a curriculum's easier density), checked
    as a model of its learner (:func:`~sb3_marl.runs.folders.check_model_file`); its tensors are read as
    data (SB3's ``set_parameters``)."""
    from sb3_marl.runs.folders import check_model_file, find_run

    path = find_run(trial_folder(log_folder, start), start.algo, start.env_id, RUN_ID).model_path
    check_model_file(path, start.algo)
    return Path(path)


def _restore_checkpoint(folder: Path, ray_checkpoint: Any) -> int:
    """Put the trial's newest checkpoint that loads in ``<folder>/checkpoint`` (Ray's, when Ray
    restarted the trial; the previous one, when a kill came between its two renames; a damaged one
    is moved aside: :func:`~sb3_marl.benchmark.repair.restore_checkpoint`); its AV-steps (0: none)."""
    from sb3_marl.benchmark.repair import restore_checkpoint

    checkpoint = folder / CHECKPOINT
    if ray_checkpoint is not None:
        with ray_checkpoint.as_directory() as directory:
            if Path(directory).resolve() != checkpoint.resolve():
                shutil.rmtree(checkpoint, ignore_errors=True)
                shutil.copytree(directory, checkpoint)
    restored = restore_checkpoint(folder)
    if restored.damaged:  # the launcher repairs a local grid before it starts; Ray's restarts and storage grids here
        print(f"trial {folder.name}: {restored.summary()}")
    return restored.timesteps


def _record_attempt(folder: Path, spec: TrialSpec, config: dict[str, Any], resumed_at: int) -> dict[str, Any]:
    """``trial.json`` with this attempt (time, host, Ray node, process, AV-steps it resumes at) added
    (a new one where it is unreadable, that one moved aside); returned."""
    from sb3_marl.benchmark.repair import move_aside

    info = None
    if (folder / TRIAL).is_file():
        try:
            info = read_trial_info(folder / TRIAL)
        except ValueError as error:
            print(f"trial {spec.trial_id}: {error}: moved aside to {move_aside(folder / TRIAL).name}")
    if info is None:
        info = {
            "trial": spec.to_dict(),
            "trial_id": spec.trial_id,
            "env_id": spec.env_id,
            "hyperparams": spec.hyperparams,
            **{key: config[key] for key in SETTINGS},
            "attempts": [],
        }
    import ray

    attempt = {"started": time.strftime("%Y-%m-%dT%H:%M:%S"), "host": socket.gethostname(), "pid": os.getpid()}
    if ray.is_initialized():  # the Ray node (several may share a host)
        attempt["node"] = ray.get_runtime_context().get_node_id()
    info["attempts"].append({**attempt, "resumed_at_timesteps": resumed_at})
    write_json(folder / TRIAL, info)
    return info


def paper_evaluation(model: Any, env_id: str, config: dict[str, Any] | None) -> dict[str, Any]:
    """The paper's final evaluation of a trained model: :data:`FINAL_EVAL_EPISODES` seeded
    episodes (seeds 10000..), sampled actions, under both supervisor protocols, with the traffic
    metrics of each (``traffic``)."""
    from sb3_marl.algos.common.policies import model_policy, uses_action_masks
    from sb3_marl.envs import scenario_of
    from sb3_marl.envs.config import supervisor_version
    from sb3_marl.evaluation import evaluate_protocols, protocol_label
    from sb3_marl.runs.experiment import EVAL_SEED_OFFSET

    result = evaluate_protocols(model_policy(model), env_id, FINAL_EVAL_EPISODES, EVAL_SEED_OFFSET, config, traffic=True)
    for summary in (result, result["supervisor_off"]):
        summary.pop("trips")  # the traffic metrics stay; trip records: benchmarks/heldout_evaluation.py --traffic
    return {
        "supervisor_version": supervisor_version(config, scenario_of(env_id)),
        "episodes": FINAL_EVAL_EPISODES,
        "seeds": [EVAL_SEED_OFFSET, EVAL_SEED_OFFSET + FINAL_EVAL_EPISODES - 1],
        "protocol": protocol_label(False, uses_action_masks(model)),
        **result,
    }


def reevaluate_trial(folder: Path) -> bool:
    """Replace a finished trial's final evaluation (``paper_evaluation`` of its ``result.json``) by
    one under both supervisor protocols (same model, seeds and episodes) where it lacks the
    policy-alone protocol, the yields or the traffic metrics, or was made under another version of
    the safety supervisor; the supervisor-on return of an earlier evaluation is kept in ``note`` if
    it differs. Returns whether the trial was re-evaluated."""
    from sb3_marl.envs import scenario_of
    from sb3_marl.envs.config import supervisor_version
    from sb3_marl.runs.folders import find_run

    result = read_json_object(folder / RESULT)
    if "trial" not in result:
        raise ValueError(f"{folder / RESULT} has no 'trial' entry: not a finished trial's result.")
    try:
        spec = TrialSpec(**result["trial"])
    except (ValueError, TypeError) as error:
        raise ValueError(f"{folder / RESULT}: 'trial' {error}") from None
    earlier = result.get("paper_evaluation") or {}
    run = find_run(folder, spec.algo, spec.env_id, RUN_ID)
    version = supervisor_version(run.env_config, scenario_of(spec.env_id))
    if (
        earlier.get("supervisor_version") == version
        and "yields_per_episode" in earlier.get("supervisor_off", {})
        and "traffic" in earlier
    ):
        return False
    evaluation = paper_evaluation(run.load_model("cpu"), spec.env_id, run.env_config)
    if "note" in earlier:
        evaluation["note"] = earlier["note"]
    if earlier and abs(earlier["return_mean"] - evaluation["return_mean"]) > 1e-9:
        before = f"supervisor v{earlier.get('supervisor_version', 2)}"
        evaluation["note"] = (
            evaluation.get("note", "") + f" Before the re-evaluation ({before}): return {earlier['return_mean']:.4f}."
        ).strip()
    write_json(folder / RESULT, {**result, "paper_evaluation": evaluation})
    return True


__all__ = ["CHECKPOINT", "RESULT", "SETTINGS", "TRIAL", "reevaluate_trial", "run_trial", "trial_folder"]
