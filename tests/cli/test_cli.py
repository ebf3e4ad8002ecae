"""The sb3-marl command line: rl-zoo log layout, TensorBoard metrics, evaluate, plot, video, resume,
interruption and bad input. Real training runs, kept tiny (a few thousand AV-steps)."""

import argparse
import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pandas as pd
import pytest
import yaml
from figures import legend_labels, line_data, panels, png_size, saved_figures
from stable_baselines3 import A2C
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sb3_marl.algos.a2c import MaskableA2C
from sb3_marl.cli import build_parser, main
from sb3_marl.runs.callbacks import atomic_save

ENV = "sb3_marl/LaneChange-density1-v0"
ENV_NAME = "sb3_marl-LaneChange-density1-v0"
# density 1: copies with 1, 2 and 3 AVs = 6 slots; 20-step rollouts = 120 AV-steps per update
TINY = [
    "-n",
    "1200",
    "--eval-freq",
    "600",
    "--eval-episodes",
    "2",
    "--save-freq",
    "600",
    "-params",
    "n_steps:20",
    "--log-interval",
    "1",
    "--verbose",
    "0",
]


def run_dir(folder: Path, exp_id: int, algo: str = "ma2c") -> Path:
    return folder / algo / f"{ENV_NAME}_{exp_id}"


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    """Two identical tiny MA2C runs (ids 1 and 2, same seed) in one log folder."""
    folder = tmp_path_factory.mktemp("logs")
    for _ in range(2):
        assert main(["train", "-f", str(folder), "--seed", "3", *TINY]) == 0
    return folder


def test_train_writes_rl_zoo_layout(logs):
    run = run_dir(logs, 1)
    for name in (
        f"{ENV_NAME}.zip",
        "best_model.zip",
        "rl_model_600_steps.zip",
        "rl_model_1200_steps.zip",
        "evaluations.npz",
        "monitor.csv",
        f"{ENV_NAME}/config.yml",
        f"{ENV_NAME}/args.yml",
    ):
        assert (run / name).is_file(), name
    assert not list(run.glob(".*partial*")), "no temporary files left"
    config = yaml.load((run / ENV_NAME / "config.yml").read_text(), Loader=yaml.UnsafeLoader)
    assert config["n_steps"] == 20 and config["reward_mode"] == "local" and config["architecture"] == "shared"
    args = yaml.load((run / ENV_NAME / "args.yml").read_text(), Loader=yaml.UnsafeLoader)
    assert args["algo"] == "ma2c" and args["seed"] == 3
    evaluations = np.load(run / "evaluations.npz")
    assert evaluations["timesteps"].tolist() == [600, 1200]
    assert evaluations["results"].shape == (2, 2) and evaluations["ep_lengths"].shape == (2, 2)
    assert ((evaluations["collision_rate"] >= 0) & (evaluations["collision_rate"] <= 1)).all()
    assert MaskableA2C.load(run / f"{ENV_NAME}.zip").num_timesteps == 1200


def test_same_seed_and_flags_give_same_results(logs, tmp_path):
    first, second = np.load(run_dir(logs, 1) / "evaluations.npz"), np.load(run_dir(logs, 2) / "evaluations.npz")
    np.testing.assert_array_equal(first["results"], second["results"])
    outputs = []
    for exp_id in (1, 2):
        out = tmp_path / f"eval{exp_id}.json"
        assert main(["evaluate", "-f", str(logs), "--exp-id", str(exp_id), "--eval-episodes", "3", "-o", str(out)]) == 0
        outputs.append(json.loads(out.read_text()))
    assert outputs[0]["returns"] == outputs[1]["returns"]
    assert outputs[0]["collision_rate"] == outputs[1]["collision_rate"]


def test_tensorboard_has_driving_metrics_and_reward_terms(logs):
    runs = sorted((logs / "tensorboard" / ENV_NAME).iterdir())
    assert [r.name for r in runs] == ["MA2C_1", "MA2C_2"]
    events = EventAccumulator(str(runs[0])).Reload()
    tags = set(events.Tags()["scalars"])
    for metric in (
        "collision_rate",
        "success_rate",
        "speed_mean",
        "headway_mean",
        "acceleration_std",
        "lane_changes_per_episode",
    ):
        assert f"rollout/{metric}" in tags and f"eval/{metric}" in tags, metric
    for term in ("safety", "headway", "speed", "comfort", "harsh_acceleration", "lane_change"):
        assert f"rollout/reward_{term}" in tags, term
    assert {"rollout/episode_return", "eval/mean_reward", "train/value_loss", "rollout/ep_rew_mean"} <= tags
    traffic = {"eval/traffic/flow_veh_h", "eval/traffic/ttc_below_3.0_share", "eval/supervisor_off/traffic/flow_veh_h"}
    assert traffic <= tags  # the traffic view of each periodic evaluation
    speeds = [event.value for event in events.Scalars("rollout/speed_mean")]
    assert all(15 < v < 40 for v in speeds)  # m/s: the scenario's speed range
    collisions = [event.value for event in events.Scalars("eval/collision_rate")]
    assert [e.step for e in events.Scalars("eval/collision_rate")] == [600, 1200]
    assert all(0 <= v <= 1 for v in collisions)


def test_evaluate_prints_and_saves_the_paper_metrics(logs, capsys):
    with saved_figures() as figures:
        argv = ["enjoy", "-f", str(logs), "--exp-id", "1", "--load-best", "--eval-episodes", "3", "--with-baselines"]
        assert main(argv) == 0
    result = json.loads((run_dir(logs, 1) / "evaluation.json").read_text())
    for key in (
        "return_mean",
        "return_std",
        "collision_rate",
        "success_rate",
        "speed_mean",
        "headway_mean",
        "acceleration_std",
        "lane_changes_per_episode",
    ):
        assert np.isfinite(result[key]), key
    assert result["model"].endswith("best_model.zip") and result["seeds"] == [10_000, 10_002]
    assert result["return_mean"] == pytest.approx(np.mean(result["returns"]))
    assert sorted(result["baselines"]) == ["cruise", "idm-mobil", "random"]
    assert result["baselines"]["idm-mobil"]["collision_rate"] == 0.0
    assert result["baselines"]["cruise"]["lane_changes_per_episode"] == 0.0  # always IDLE: keeps its lane
    # `baselines` scores the same episodes with the same flags: its rows over every AV count are these
    assert main(["baselines", "--eval-episodes", "3", "-o", str(logs / "baselines.md")]) == 0
    rows = json.loads((logs / "baselines.json").read_text())
    for row in [row for row in rows if row["n_avs"] == "all"]:
        reference = result["baselines"][row["policy"]]
        reference = reference if row["supervisor"] == "on" else reference["supervisor_off"]
        assert row["returns"] == reference["returns"], row["policy"]
    out = capsys.readouterr().out
    assert f"| ma2c | {result['num_timesteps']} |" in out and "| random | - |" in out and "| idm-mobil | - |" in out
    # the traffic view beside it: a table of both protocols and every policy, and the trip records
    assert "| policy | timesteps | supervisor | flow [veh/h] |" in out and "trips" not in result
    assert np.isfinite(result["traffic"]["flow_veh_h"]) and "traffic" in result["supervisor_off"]
    trips = pd.read_csv(run_dir(logs, 1) / "evaluation_trips.csv")
    assert set(trips["policy"]) == {"ma2c", "random", "cruise", "idm-mobil", "all human (no AV)"}
    assert set(trips["supervisor"]) == {"on", "off", "-"}
    assert trips.groupby(["policy", "supervisor"])["seed"].nunique().eq(3).all()
    assert "| all human (no AV) | - | - |" in out and set(trips[trips["policy"] == "all human (no AV)"]["vType"]) == {"HDV"}
    # the time-space diagram of the evaluation's first episode: the policy with the supervisor above
    # the all-human reference, one panel per lane; every vehicle starts where its trip record does
    diagram = run_dir(logs, 1) / "evaluation_time_space.png"
    figure = figures[diagram]
    assert figure.get_suptitle() == f"{ENV}, episode seed 10000 (AVs: thick, black edge)"
    rows = {"ma2c, supervisor on": ("ma2c", "on"), "all human (no AV)": ("all human (no AV)", "-")}
    titles = [f"{row}: lane band {band}" for row in rows for band in (0, 1)]
    assert [ax.get_title() for ax in panels(figure)] == titles and png_size(diagram) == (2 * 420, 2 * 320)
    for row, (policy, supervisor) in rows.items():
        mine = [ax for ax in panels(figure) if ax.get_title().startswith(row + ":")]
        starts = sorted(x for ax in mine for lines in ax.collections for (t, x), _ in lines.get_segments() if t == 0)
        thick = sorted(x for ax in mine for line in ax.get_lines() for t, x in line.get_xydata() if t == 0)
        first = trips[(trips["policy"] == policy) & (trips["supervisor"] == supervisor) & (trips["seed"] == 10_000)]
        assert starts == pytest.approx(sorted(first["departPos"]), abs=1e-9), row
        assert thick == pytest.approx(sorted(first[first["vType"] == "AV"]["departPos"]), abs=1e-9), row


def test_plot_and_rl_zoo3_plots_read_our_logs(logs, tmp_path, monkeypatch, capsys):
    from stable_baselines3.common.monitor import load_results

    with saved_figures() as figures:
        assert main(["plot", "--algo", "ma2c", "mappo", "-f", str(logs), "-w", "2", "-o", str(tmp_path / "plots")]) == 0
    curves = {}
    for name in ("train_return.png", "eval_return.png", "collision_rate.png"):
        path = tmp_path / "plots" / name
        (ax,) = panels(figures[path])
        curves[name] = line_data(ax)
        assert png_size(path) == (700, 450) and legend_labels(ax) == list(curves[name]), name
        assert ax.get_xlabel() == "Timesteps (AV-steps)", name
    # each run's curves (labelled with its flags) are its logs: training returns over 2 episodes
    # (-w 2), evaluations with the supervisor and without it (dashed)
    labels = {exp_id: f"ma2c run {exp_id} (n_steps=20)" for exp_id in (1, 2)}
    assert list(curves["train_return.png"]) == list(labels.values())
    for exp_id, label in labels.items():
        run = run_dir(logs, exp_id)
        returns = load_results(str(run))["r"].to_numpy()
        np.testing.assert_allclose(curves["train_return.png"][label][1], (returns[1:] + returns[:-1]) / 2)
        evaluations = np.load(run / "evaluations.npz")
        for name, key in (("eval_return.png", "results"), ("collision_rate.png", "collision_rate")):
            for supervisor, prefix in (("on", ""), ("off", "supervisor_off_")):
                x, y = curves[name][f"{label}, supervisor {supervisor}"]
                values = evaluations[prefix + key]
                assert x.tolist() == evaluations["timesteps"].tolist(), name
                np.testing.assert_allclose(y, values.mean(axis=1) if key == "results" else values, err_msg=name)
    out = capsys.readouterr().out
    assert f"no runs of mappo on sb3_marl/LaneChange-density1-v0 under {logs}/: left out of the plots" in out

    from matplotlib import pyplot as plt
    from rl_zoo3.plots.all_plots import all_plots
    from rl_zoo3.plots.plot_train import plot_train

    out = tmp_path / "all_plots"
    monkeypatch.setattr(
        sys, "argv", ["all_plots", "-a", "ma2c", "-e", "LaneChange-density1", "-f", str(logs), "--no-display", "-o", str(out)]
    )
    all_plots()
    with open(f"{out}.pkl", "rb") as file:
        curves = pickle.load(file)["LaneChange-density1"][f"MA2C-{logs}"]
    assert curves["timesteps"].tolist() == [600, 1200]
    expected = np.mean([np.load(run_dir(logs, i) / "evaluations.npz")["results"].mean(axis=1) for i in (1, 2)], axis=0)
    np.testing.assert_allclose(curves["mean"], expected)

    plt.close("all")
    monkeypatch.setattr(sys, "argv", ["plot_train", "-a", "ma2c", "-e", "LaneChange-density1", "-f", str(logs), "-w", "2"])
    monkeypatch.setattr(plt, "show", lambda: None)
    plot_train()
    assert len(plt.gca().lines) == 2  # one training curve per run, from monitor.csv
    plt.close("all")


def test_record_video_writes_a_playable_mp4(logs, tmp_path, capsys):
    path = tmp_path / "replay.mp4"
    assert main(["record-video", "-f", str(logs), "-o", str(path)]) == 0
    frames = list(imageio.get_reader(path).iter_data())
    assert f"{len(frames)} frames at 5 fps" in capsys.readouterr().out
    assert 2 <= len(frames) <= 101  # one frame per policy step of one episode (100 steps at most)
    height = frames[0].shape[0]
    assert height >= 240 and frames[0].shape[1] == 1200 and frames[0].std() > 0  # the road is drawn, not a black frame
    band = frames[0][:40]  # the text band: light background with dark text (time, legend, AV lines)
    assert (band.mean(axis=2) > 230).mean() > 0.8 and (band.mean(axis=2) < 100).sum() > 200


@pytest.mark.parametrize("env_id", ["sb3_marl/LaneChange-density3-v0", "sb3_marl/Merge-density3-v0"])
def test_the_video_camera_frames_every_av_on_the_road(env_id):
    """Every frame of random-policy episodes at the densest traffic shows every AV still on the road
    (its centre inside the frame's width), at a zoom within the camera's bounds."""
    from sb3_marl.envs import make_scenario
    from sb3_marl.evaluation.baselines import RandomPolicy
    from sb3_marl.evaluation.episodes import run_episodes
    from sb3_marl.evaluation.video import MIN_SCALING, SCALING, VIEW, frame
    from sb3_marl.sim import kernel

    env = make_scenario(env_id, VIEW, render_mode="rgb_array")
    outside, zooms = [], []

    def check(env, info):
        frame(env, info)
        zooms.append(env.viewer.sim_surface.scaling)
        for i, row in enumerate(env.state[: env.n_avs]):
            x, _ = env.viewer.sim_surface.pos2pix(row[kernel.X], row[kernel.Y])
            if row[kernel.COLLIDABLE] > 0 and not 0 <= x < VIEW["screen_width"]:
                outside.append((info["step"], i, x))

    run_episodes(env, RandomPolicy(), 2, seed=3, on_step=check)
    env.close()
    assert not outside and MIN_SCALING <= min(zooms) <= max(zooms) <= SCALING and len(set(zooms)) > 1


def test_videos_without_the_video_extra_say_how_to_get_it(logs, tmp_path, monkeypatch, capsys):
    """imageio-ffmpeg absent (the runtime install, without the `video` extra): record-video and
    push-to-hub stop before any work with the pip command; push-to-hub --no-video still builds."""
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # `import imageio_ffmpeg` raises ImportError
    assert main(["record-video", "-f", str(logs), "-o", str(tmp_path / "replay.mp4")]) == 1
    assert "pip install 'sb3-marl[video]'" in capsys.readouterr().err and not (tmp_path / "replay.mp4").exists()
    push = ["push-to-hub", "-f", str(logs), "-orga", "someone", "--eval-episodes", "1", "--dry-run"]
    assert main([*push, str(tmp_path / "hub")]) == 1
    assert "imageio_ffmpeg is not installed" in capsys.readouterr().err and not (tmp_path / "hub").exists()
    assert main([*push, str(tmp_path / "hub"), "--no-video"]) == 0 and not (tmp_path / "hub" / "replay.mp4").exists()


def test_resume_continues_the_timestep_count(logs):
    final = run_dir(logs, 1) / f"{ENV_NAME}.zip"
    assert main(["train", "-f", str(logs), "-i", str(final), *TINY[:1], "1800", *TINY[2:]]) == 0
    resumed = run_dir(logs, 3)
    assert MaskableA2C.load(resumed / f"{ENV_NAME}.zip").num_timesteps == 1800
    assert np.load(resumed / "evaluations.npz")["timesteps"].tolist() == [1800]
    assert sorted(p.name for p in resumed.glob("rl_model_*")) == ["rl_model_1800_steps.zip"]


def test_a_signal_during_compiled_code_counts_as_an_interruption():
    """Ctrl-C / SIGTERM raise KeyboardInterrupt from a Python signal handler; when the signal lands
    while numba's compiled supervisor runs, numba's dispatcher reports it as a SystemError caused
    by the KeyboardInterrupt. Both must stop training as an interruption, not as a failure."""
    import gymnasium as gym

    from sb3_marl.envs import ENV_IDS
    from sb3_marl.runs.experiment import interrupted_by_user

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    env = gym.make(ENV_IDS[3], config={"safety_supervisor": True}).unwrapped
    previous = signal.signal(signal.SIGALRM, interrupt)
    try:
        for attempt in range(8):  # the signal lands in Python or in compiled code: both count
            env.reset(seed=attempt)
            signal.setitimer(signal.ITIMER_REAL, 0.05, 0.002)
            try:
                while True:
                    _, _, terminated, truncated, _ = env.step(np.ones(env.n_avs, dtype=int))
                    if terminated or truncated:
                        env.reset()
            except BaseException as error:
                signal.setitimer(signal.ITIMER_REAL, 0)
                assert interrupted_by_user(error), repr(error)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as cause:
            raise SystemError("CPUDispatcher(...) returned a result with an exception set") from cause
    except SystemError as error:
        assert interrupted_by_user(error)
    assert not interrupted_by_user(SystemError("a real failure")) and not interrupted_by_user(ValueError())


def test_sigterm_saves_the_model_and_logs(tmp_path):
    command = [
        sys.executable,
        "-m",
        "sb3_marl",
        "train",
        "-f",
        str(tmp_path),
        "-n",
        "10000000",
        "--save-freq",
        "240",
        "--eval-freq",
        "-1",
        "-params",
        "n_steps:20",
        "--verbose",
        "0",
    ]
    process = subprocess.Popen(command, env={**os.environ, "OMP_NUM_THREADS": "1"})
    run = run_dir(tmp_path, 1)
    deadline = time.time() + 120
    while not list(run.glob("rl_model_*_steps.zip")) and time.time() < deadline and process.poll() is None:
        time.sleep(0.2)
    assert process.poll() is None, "training ended before the signal"
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=60) == 143
    model = MaskableA2C.load(run / f"{ENV_NAME}.zip")
    assert model.num_timesteps >= 240
    assert (run / "monitor.csv").is_file() and list((tmp_path / "tensorboard" / ENV_NAME / "MA2C_1").iterdir())
    assert not list(run.glob(".*partial*"))


def test_atomic_save_keeps_the_previous_file_when_saving_fails(tmp_path, monkeypatch):
    model = A2C("MlpPolicy", "CartPole-v1", n_steps=8, seed=0)
    path = atomic_save(model, tmp_path / "rl_model_8_steps.zip")
    before = path.read_bytes()

    def crash(target, *args, **kwargs):
        Path(target).write_bytes(b"half a zip")
        raise KeyboardInterrupt

    monkeypatch.setattr(model, "save", crash)
    with pytest.raises(KeyboardInterrupt):
        atomic_save(model, path)
    assert path.read_bytes() == before
    assert not list(tmp_path.glob(".*partial*")), "the half-written temporary file is removed"


def test_two_processes_writing_one_file_do_not_collide(tmp_path):
    """Two benchmark launchers on one folder both rewrite ``benchmark.json``: neither may rename
    the other's temporary file away (a FileNotFoundError that ended a launcher)."""
    path = tmp_path / "benchmark.json"
    writer = (
        "import sys\nfrom sb3_marl.common.files import write_text\n"
        "for i in range(300):\n    write_text(sys.argv[1], sys.argv[2] * 1000)\n"
    )
    processes = [subprocess.Popen([sys.executable, "-c", writer, str(path), tag]) for tag in "ab"]
    assert [process.wait(timeout=120) for process in processes] == [0, 0]
    assert path.read_text() in ("a" * 1000, "b" * 1000)
    assert not list(tmp_path.glob(".*partial*"))


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["train", "--algo", "a3c"], "invalid choice: 'a3c' (choose from 'ma2c', 'maacktr'"),
        (["train", "--env", "highway-v0"], "invalid choice: 'highway-v0'"),
        (["train", "--bogus-flag"], "unrecognized arguments: --bogus-flag"),
        (["train", "--n-envs", "0"], "expected a finite value >= 1"),
        (["train", "-params", "n_steps"], "expected key:value"),
    ],
)
def test_bad_flags_are_usage_errors(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["train", "-params", "n_step:20"], "Unknown hyperparameter(s) ['n_step'] for 'ma2c': valid keys are"),
        (["train", "--algo", "madqn", "-params", "architecture:'separate'"], "Invalid architecture 'separate'"),
        (["train", "-params", "policy:'CnnPolicyX'"], "Invalid policy 'CnnPolicyX' for 'ma2c': expected one of"),
        (["train", "-params", "reward_mode:'team'"], "reward_mode"),
        (["train", "-i", "missing.zip"], "'missing.zip' is not an existing .zip model file"),
        (["evaluate", "--exp-id", "7"], "not found"),
        (["record-video"], "No run of ma2c"),
    ],
)
def test_bad_input_fails_before_any_work(argv, message, tmp_path, capsys):
    assert main([*argv, "-f", str(tmp_path)]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "ma2c").exists() and not (tmp_path / "tensorboard").exists()


def test_baselines_table(tmp_path, capsys):
    out = tmp_path / "baselines.md"
    assert main(["baselines", "--eval-episodes", "1", "-o", str(out)]) == 0
    rows = json.loads(out.with_suffix(".json").read_text())
    expected = [(p, n, s) for p in ("random", "cruise", "idm-mobil") for n in ("all", 1, 2, 3) for s in ("on", "off")]
    assert [(r["policy"], r["n_avs"], r["supervisor"]) for r in rows] == expected
    assert "| idm-mobil | 3 | on |" in out.read_text() and "ramp AVs merged" not in out.read_text()
    assert "seeds 10000..10000" in out.read_text()  # evaluate's seeds
    merge = "sb3_marl/Merge-density1-v0"
    assert main(["baselines", "--env", merge, "--eval-episodes", "1", "--supervisor", "off", "-o", str(out)]) == 0
    assert "| ramp AVs merged | time to merge [s] | stranded/ep |" in out.read_text() and "| on |" not in out.read_text()


def test_baselines_old_spellings_still_work_for_one_release(tmp_path, capsys):
    """--density, --scenario, --episodes, --out: hidden, each with a message naming the new flag."""
    out = tmp_path / "old.md"
    assert main(["baselines", "--scenario", "merge", "--density", "2", "--episodes", "1", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    renamed = {"--scenario": "--env", "--density": "--env", "--episodes": "--eval-episodes", "--out": "-o/--output"}
    for old, new in renamed.items():
        assert f"{old} is deprecated and goes in the next release: use {new}." in err
    assert "Scenario sb3_marl/Merge-density2-v0: 1 episodes per row" in out.read_text()


def test_one_name_per_idea_across_subcommands():
    """Every subcommand's visible flags spell an idea one way: episodes --eval-episodes, the
    scenario --env, an output file -o/--output, a log folder -f."""
    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    old = {"--episodes", "--n-episodes", "--out", "--density", "--scenario", "--folder-out"}
    seen = {
        (name, flag)
        for name, parser in commands.choices.items()
        for action in parser._actions
        if action.help != argparse.SUPPRESS
        for flag in action.option_strings
    }
    assert not [item for item in seen if item[1] in old]
    for name, parser in commands.choices.items():
        flags = {flag for action in parser._actions if action.help != argparse.SUPPRESS for flag in action.option_strings}
        if "--output" in flags:
            assert "-o" in flags, name
        if any("episode" in flag for flag in flags if "with" not in flag and "window" not in flag):
            assert "--eval-episodes" in flags, (name, sorted(flags))


def test_two_trainings_started_together_get_their_own_run_folders(tmp_path):
    """Two `train` processes started at once into one log folder: each creates its own run folder
    (ids 1 and 2), saves its own model and writes its own TensorBoard folder."""
    command = [
        str(Path(sys.executable).parent / "sb3-marl"),
        "train",
        "-n",
        "200",
        "--eval-freq",
        "200",
        "--eval-episodes",
        "1",
        "-f",
        str(tmp_path),
        "-params",
        "n_steps:20",
    ]
    processes = [subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for _ in range(2)]
    outputs = [p.communicate(timeout=300)[0] for p in processes]
    assert [p.returncode for p in processes] == [0, 0], outputs
    lines = [line for out in outputs for line in out.splitlines()]
    saved = sorted(line.split(" to ")[-1] for line in lines if line.startswith("Saved the model"))
    assert len(set(saved)) == 2 and all(Path(path).is_file() for path in saved)
    assert sorted(p.name for p in (tmp_path / "ma2c").iterdir()) == [f"{ENV_NAME}_1", f"{ENV_NAME}_2"]
    assert sorted(p.name for p in (tmp_path / "tensorboard" / ENV_NAME).iterdir()) == ["MA2C_1", "MA2C_2"]


def test_the_summary_of_merge_runs_has_the_merge_columns(tmp_path):
    logs, env = tmp_path / "logs", "sb3_marl/Merge-density1-v0"
    assert main(["train", "--algo", "ma2c", "--env", env, "-n", "600", "--eval-freq", "-1", "-f", str(logs)]) == 0
    assert main(["evaluate", "--algo", "ma2c", "--env", env, "--eval-episodes", "2", "-f", str(logs)]) == 0
    assert main(["summary", "-f", str(logs)]) == 0
    lines = (logs / "summary.md").read_text().splitlines()
    assert lines[0].endswith("| ramp AVs merged | time to merge [s] | stranded/ep |")
    assert len(lines) == 4 and all(line.count("|") == lines[0].count("|") for line in lines)  # on and off, every cell
    # beside a lane-change run, the columns every row has (the merge's are not)
    lane_change = "sb3_marl/LaneChange-density1-v0"
    assert main(["train", "--algo", "ma2c", "--env", lane_change, "-n", "600", "--eval-freq", "-1", "-f", str(logs)]) == 0
    assert main(["evaluate", "--algo", "ma2c", "--env", lane_change, "--eval-episodes", "2", "-f", str(logs)]) == 0
    assert main(["summary", "-f", str(logs)]) == 0
    lines = (logs / "summary.md").read_text().splitlines()
    assert "ramp AVs merged" not in lines[0] and len(lines) == 6
    assert all(line.count("|") == lines[0].count("|") for line in lines)
