"""ScenarioEvalCallback's hooks: a callback after each evaluation, a final evaluation, a resumed history."""

import subprocess
import sys

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sb3_marl.envs import ENV_IDS
from sb3_marl.runs.callbacks import ScenarioEvalCallback
from sb3_marl.runs.training import make_model, make_venv


class RecordEvaluations(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.seen: list[tuple[int, float]] = []

    def _on_step(self) -> bool:
        self.seen.append((self.num_timesteps, self.parent.last_summary["return_mean"]))
        return True


def train_with_evaluations(tmp_path, eval_freq: int) -> tuple[ScenarioEvalCallback, RecordEvaluations]:
    """MA2C on density 1 (6 AV slots) for 240 AV-steps = 40 VecEnv steps."""
    hyperparams = {"architecture": "shared", "n_steps": 10}
    venv = make_venv(ENV_IDS[1], hyperparams, seed=0)
    model = make_model("ma2c", venv, hyperparams, seed=0)
    record = RecordEvaluations()
    evaluation = ScenarioEvalCallback(
        ENV_IDS[1],
        eval_freq=eval_freq,
        n_eval_episodes=2,
        log_path=tmp_path,
        callback_after_eval=record,
        evaluate_at_end=True,
        verbose=0,
    )
    model.learn(240, callback=evaluation)
    venv.close()
    return evaluation, record


def test_callback_after_each_evaluation_and_a_final_evaluation(tmp_path):
    evaluation, record = train_with_evaluations(tmp_path, eval_freq=25)  # periodic: VecEnv step 25 only
    log = np.load(tmp_path / "evaluations.npz")
    np.testing.assert_array_equal(log["timesteps"], [150, 240])
    assert record.seen == [(150, log["results"][0].mean()), (240, log["results"][1].mean())]
    assert evaluation.final_summary()["timesteps"] == 240


def test_no_second_final_evaluation_when_the_last_one_was_at_the_end(tmp_path):
    train_with_evaluations(tmp_path, eval_freq=20)
    np.testing.assert_array_equal(np.load(tmp_path / "evaluations.npz")["timesteps"], [120, 240])


def test_load_history_keeps_the_evaluations_up_to_the_checkpoint(tmp_path):
    train_with_evaluations(tmp_path, eval_freq=25)
    log = np.load(tmp_path / "evaluations.npz")
    resumed = ScenarioEvalCallback(ENV_IDS[1], eval_freq=25, verbose=0)
    resumed.load_history(tmp_path / "evaluations.npz", up_to_timesteps=150)
    final = resumed.final_summary()
    assert final["timesteps"] == 150 and final["return_mean"] == log["results"][0].mean()
    assert final["collision_rate"] == log["collision_rate"][0]
    assert resumed.best_mean_reward == log["results"][0].mean()


def test_episode_records_from_step_arrays_equal_those_from_the_copy():
    """The driving-metrics callback builds episodes from the VecEnv's step arrays (add_slot_step),
    evaluation from the copy's info (add_step): on a real supervised episode both give the same record."""
    import numpy as np

    from sb3_marl.envs import LaneChangeEnv
    from sb3_marl.evaluation import EpisodeRecord
    from wrappers.step_arrays import StepArrays, copy_arrays

    env = LaneChangeEnv(config={"density": 3, "safety_supervisor": True})
    env.reset(seed=3)
    rng = np.random.default_rng(0)
    from_copy, from_slots, done = EpisodeRecord(), EpisodeRecord(), False
    while not done:
        actions = np.array([rng.choice(np.flatnonzero(row)) for row in env.action_masks()])
        _, reward, terminated, truncated, info = env.step(actions)
        from_copy.add_step(reward, info)
        arrays = StepArrays.join([copy_arrays(info)], np.zeros(env.n_avs, dtype=int), np.arange(env.n_avs))
        for slot in range(env.n_avs):
            from_slots.add_slot_step(arrays, slot)
        done = terminated or truncated
    assert from_copy.length > 1 and from_copy.lane_changes > 0 and from_copy.interventions > 0
    for field in ("length", "crashed", "lane_changes", "interventions", "av_steps"):
        assert getattr(from_slots, field) == getattr(from_copy, field), field
    assert from_slots.episode_return == from_copy.episode_return


def test_progress_written_to_a_file_is_ten_short_lines(tmp_path):
    """``train -P`` with its output in a file (as ``make run > log``): no bar redraws, a line per tenth."""
    log = tmp_path / "train.log"
    command = [sys.executable, "-m", "sb3_marl", "train", "--algo", "ma2c", "-n", "1200", "--eval-freq", "-1", "-P"]
    with log.open("w") as out:
        subprocess.run([*command, "-f", str(tmp_path / "logs")], stdout=out, stderr=subprocess.STDOUT, check=True, timeout=600)
    lines = log.read_text().splitlines()
    progress = [line for line in lines if line.startswith("progress: ")]
    assert len(progress) == 10 and progress[-1].startswith("progress: 1200/1200 AV-steps (100 %)")
    assert max(map(len, lines)) < 300 and not any(line and not line.strip() for line in lines)
    assert "\r" not in log.read_text() and "\x1b" not in log.read_text()
