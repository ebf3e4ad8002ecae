"""The paper-reproduction benchmark on a real local Ray instance: tiny grids of 2 trials."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sb3_marl.benchmark import GRIDS, make_grid
from sb3_marl.benchmark.figures import acceleration_traces
from sb3_marl.benchmark.grid import VARIANTS
from sb3_marl.benchmark.report import MANIFEST, write_report
from sb3_marl.benchmark.runner import run_benchmark
from sb3_marl.benchmark.statistics import load_trials
from sb3_marl.cli import main

ray = pytest.importorskip("ray")

#: 2 trials (MA2C with local and with global reward) on density 1, one seed
TINY = {"grid": "reward", "seeds": 1, "densities": (1,), "verbose": 0}


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, configure_logging=False, log_to_driver=False)
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def tiny_benchmark(local_ray, tmp_path_factory) -> Path:
    """The tiny grid run once: 600 AV-steps (300 env steps) per trial, evaluated every episode."""
    folder = tmp_path_factory.mktemp("benchmark")
    outcome = run_benchmark(log_folder=folder, budget=0.0003, eval_every_episodes=1, **TINY)
    assert sorted(outcome.completed) == ["ma2c_density1_default_seed0", "ma2c_density1_global-reward_seed0"]
    assert not outcome.failed and not outcome.skipped
    return folder


def test_grids_hold_each_trial_once():
    from sb3_marl.benchmark.grid import GRID_SEEDS

    assert GRID_SEEDS == 3  # the authors' code's seeds, as the committed grids ran
    assert len(make_grid("baselines")) == 4 * 3 * GRID_SEEDS
    assert len(make_grid("reward")) == 2 * 3 * GRID_SEEDS
    # the paper grid shares the default MA2C trials between experiments: 4 algos + 5 MA2C variants
    paper = make_grid("paper")
    assert len(paper) == (4 + 5) * 3 * GRID_SEEDS == len({spec.trial_id for spec in paper})
    assert set(GRIDS) == {
        "paper",
        "baselines",
        "reward",
        "sharing",
        "comfort",
        "politeness",
        "penalty",
        "safety",
        "ctde",
        "rule-prior",
        "merge",
        "curriculum",
        "mobil-safety",
        "copies",
        "cadence",
        "merge-cadence",
    }
    from sb3_marl.benchmark.grid import EXPERIMENTS
    from sb3_marl.benchmark.tables import PAPER_FINDINGS

    assert set(PAPER_FINDINGS) == set(EXPERIMENTS)  # every experiment has its title in the report
    assert {(s.algo, s.variant) for s in make_grid("rule-prior", seeds=3)} == {
        ("ma2c", "rule-prior"),
        ("mappo", "rule-prior"),
        ("ma2c", "rule-prior-sharp"),
        ("ma2c", "rule-prior-dropout"),
        ("ma2c", "rule-prior-strong"),
        ("ma2c", "rule-prior-sharpen"),
        ("ma2c", "rule-prior-sharpen-0.1"),
        ("ma2c", "rule-prior-sharpen-0.2"),
        ("ma2c", "rule-prior-sharpen-free"),
        ("ma2c", "rule-prior-agreement"),
        ("ma2c", "rule-prior-agreement-0.5"),
        ("ma2c", "rule-prior-agreement-0.75"),
        ("ma2c", "rule-prior-agreement-shadow"),
        ("ma2c", "rule-prior-agreement-0.5-executed"),
        ("mappo", "rule-prior-agreement-0.5"),
        ("madqn", "rule-prior"),
    }
    merge = make_grid("merge", densities=(2,), seeds=1)
    assert [spec.env_id for spec in merge] == ["sb3_marl/Merge-density2-v0"] * 4
    assert merge[1].trial_id == "ma2c_density2_merge_seed0" and merge[1].n_timesteps(1.0) == 3_000_000
    mobil = make_grid("mobil-safety", densities=(3,), seeds=1)[-1]
    assert mobil.env_id == "sb3_marl/Merge-density3-v0"
    assert mobil.hyperparams == {"env_config": {"supervisor_mobil_safety": True}}
    safety = make_grid("safety", seeds=1)
    assert [spec.variant for spec in safety] == ["default"] * 3 + ["safety-training"] * 3
    assert safety[-1].hyperparams == VARIANTS["safety-training"] and safety[-1].hyperparams["supervisor_dropout"] > 0
    assert make_grid("penalty", seeds=1)[-1].hyperparams == {"intervention_penalty": 0.0}
    assert make_grid("cadence", seeds=1)[0].hyperparams == {"per_agent_updates": True, "scale_lr_by_slots": False}
    spec = make_grid("comfort", densities=(2,), seeds=1)[1]
    assert spec.hyperparams == {"env_config": {"comfort": False}}
    assert spec.n_timesteps(1.0) == 3_000_000  # 1M env steps at 3 AV-steps per env step (copies of 2+3+4 AVs)
    assert spec.eval_freq(200) == 60_000  # 200 episodes x 100 steps x 3 AV-steps


def test_trials_write_the_rl_zoo_layout_and_tensorboard(tiny_benchmark):
    for variant, reward_mode in (("default", "local"), ("global-reward", "global")):
        trial = tiny_benchmark / "trials" / f"ma2c_density1_{variant}_seed0"
        run = trial / "ma2c" / "sb3_marl-LaneChange-density1-v0_1"
        assert (run / "sb3_marl-LaneChange-density1-v0.zip").is_file()
        config = (run / "sb3_marl-LaneChange-density1-v0" / "config.yml").read_text()
        assert f"- {reward_mode}" in config
        evaluations = np.load(run / "evaluations.npz")
        assert evaluations["results"].shape[1] == 3  # the paper's 3 episodes per evaluation
        assert np.all(np.diff(evaluations["timesteps"]) > 0)
        result = json.loads((trial / "result.json").read_text())
        assert result["num_timesteps"] >= 600 and result["final_evaluation"]["timesteps"] == result["num_timesteps"]
        assert evaluations["timesteps"][-1] == result["num_timesteps"]  # a final evaluation at the end
        paper = result["paper_evaluation"]  # the paper's: 30 seeded episodes of the trained model, sampled
        assert paper["episodes"] == len(paper["returns"]) == 30 and paper["seeds"] == [10_000, 10_029]
        assert paper["return_mean"] == pytest.approx(np.mean(paper["returns"])) and "sampled" in paper["protocol"]
        assert paper["traffic"]["flow_veh_h"] > 0 and "traffic" in paper["supervisor_off"] and "trips" not in paper
        events = list((trial / "tensorboard").rglob("events.out.tfevents.*"))
        accumulator = EventAccumulator(str(events[0].parent)).Reload()
        assert "eval/mean_reward" in accumulator.Tags()["scalars"]


def test_report_writes_the_table_and_the_figures(tiny_benchmark, tmp_path, capsys):
    # an earlier report's outputs (its manifest) that this grid does not produce go; other files stay
    stale = ["comfort.png", "learning_curves_withdrawn.png", "cooperative_lane_change.json"]
    for name in [*stale, "notes.md"]:
        (tmp_path / name).write_text("earlier")
    (tmp_path / MANIFEST).write_text(json.dumps(stale))
    assert main(["benchmark", "report", "-f", str(tiny_benchmark), "-o", str(tmp_path)]) == 0
    table = (tmp_path / "paper_table.md").read_text()
    trials = {t.spec.variant: t for t in load_trials(tiny_benchmark)}
    for label, variant in (("local reward", "default"), ("global reward", "global-reward")):
        final = trials[variant].result["paper_evaluation"]  # the paper's 30-episode final evaluation
        assert final["return_mean"] != trials[variant].result["final_evaluation"]["return_mean"]
        iqm = np.sort(final["returns"])[7:23].mean()  # rliable's IQM of 30 returns: the middle 16
        assert f"| {label} | 1 | 1 | 300 | {final['return_mean']:.2f} ± 0.00 | {iqm:.2f} [" in table
    assert "| MA2C | 1 | 1 | 300 |" in table and "58.00 ± 9.31" in table  # beside the paper's number
    assert "budget 0.0003" in table.lower()
    # the hand-written policies on the same 30 episodes, and the learners against IDM/MOBIL
    assert "## Beyond the paper: hand-written reference policies" in table
    assert "| idm-mobil | 1 | 30 | " in table and "| cruise | 1 | 30 | " in table
    assert "- Here, density 1: against IDM/MOBIL (" in table
    for name in ("learning_curves_reward", "learning_curves_baselines", "final_returns"):
        png = tmp_path / f"{name}.png"
        assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"
    # the traffic view: the all-human reference, the hand-written policies and each curve, both protocols
    traffic = (tmp_path / "traffic.md").read_text()
    flow = trials["default"].result["paper_evaluation"]["traffic"]["flow_veh_h"]
    assert f"| lane-change | 1 | ma2c (default) | 1 | on | {flow:.0f} |" in traffic
    for policy in ("all human (no AV) | - | -", "idm-mobil | - | on", "idm-mobil | - | off", "ma2c (global-reward) | 1 | off"):
        assert f"| lane-change | 1 | {policy} | " in traffic
    for name in ("traffic", "time_space_lane-change"):
        assert (tmp_path / f"{name}.png").stat().st_size > 10_000
    assert not (tmp_path / "time_space_merge.png").exists()  # no merge trial
    assert not (tmp_path / "comfort.png").exists()  # no comfort-off trial in this grid
    assert not (tmp_path / "cooperative_lane_change.json").exists()  # experiment 6 needs density 2 or 3
    assert not (tmp_path / "learning_curves_withdrawn.png").exists()  # no such experiment any more
    assert (tmp_path / "notes.md").read_text() == "earlier"
    assert "wrote" in capsys.readouterr().out


def test_status_lists_where_each_trial_stands(tiny_benchmark, capsys):
    # the comfort grid shares its default MA2C trial with the reward grid: finished; comfort off: not started
    assert (
        main(["benchmark", "status", "--grid", "comfort", "--seeds", "1", "--densities", "1", "-f", str(tiny_benchmark)]) == 0
    )
    out = capsys.readouterr().out
    assert "1 of 2 trials finished, 0 unfinished (continue from their checkpoint), 1 not started" in out
    final = json.loads((tiny_benchmark / "trials" / "ma2c_density1_default_seed0" / "result.json").read_text())
    row = next(line for line in out.splitlines() if line.startswith("ma2c_density1_default_seed0 "))
    assert row.split()[1:5] == ["finished", f"{final['num_timesteps']:,}", "/", "600"]
    assert f"{final['paper_evaluation']['return_mean']:.2f}" in row
    assert next(line for line in out.splitlines() if line.startswith("ma2c_density1_no-comfort_seed0 ")).split()[1:3] == [
        "not",
        "started",
    ]
    assert main(["benchmark", "status", "-f", str(tiny_benchmark / "missing")]) == 2
    assert "No benchmark in" in capsys.readouterr().err and not (tiny_benchmark / "missing").exists()


def test_second_invocation_skips_finished_trials_and_resumes_unfinished(tiny_benchmark):
    results = sorted((tiny_benchmark / "trials").glob("*/result.json"))
    before = {path: path.read_text() for path in results}
    outcome = run_benchmark(log_folder=tiny_benchmark, budget=0.0003, eval_every_episodes=1, **TINY)
    assert sorted(outcome.skipped) == ["ma2c_density1_default_seed0", "ma2c_density1_global-reward_seed0"]
    assert outcome.completed == [] and {path: path.read_text() for path in results} == before
    # an unfinished trial (no result.json) continues from its checkpoint instead of starting over
    unfinished = results[1]
    final = json.loads(unfinished.read_text())["final_evaluation"]
    unfinished.unlink()
    outcome = run_benchmark(log_folder=tiny_benchmark, budget=0.0003, eval_every_episodes=1, **TINY)
    assert outcome.completed == [unfinished.parent.name] and len(outcome.skipped) == 1
    attempts = json.loads((unfinished.parent / "trial.json").read_text())["attempts"]
    assert attempts[-1]["resumed_at_timesteps"] == final["timesteps"]
    assert json.loads(unfinished.read_text())["final_evaluation"] == final


def test_a_curriculum_trial_starts_from_the_easier_densitys_model(local_ray, tmp_path):
    """The curriculum's density-2 trial runs after density 1's (added to the grid), from its final
    weights: its first evaluation is of a trained model, not of a fresh one."""
    from sb3_marl.runs.folders import find_run

    grid = make_grid("curriculum", densities=(2,), seeds=1)
    assert [spec.trial_id for spec in grid] == [
        "ma2c_density2_merge_seed0",
        "ma2c_density1_merge_seed0",  # added: the curriculum starts from it
        "ma2c_density2_merge-curriculum_seed0",
    ]
    scratch, start, curriculum = grid
    assert curriculum.starts_from == start and make_grid("curriculum", densities=(3,), seeds=1)[-1].starts_from == curriculum
    outcome = run_benchmark("curriculum", tmp_path, budget=0.0003, seeds=1, densities=(2,), eval_every_episodes=1, verbose=0)
    assert sorted(outcome.completed) == sorted(spec.trial_id for spec in grid) and not outcome.failed
    started = json.loads((tmp_path / "trials" / curriculum.trial_id / "trial.json").read_text())["attempts"][0]["started"]
    finished = (tmp_path / "trials" / start.trial_id / "result.json").stat().st_mtime
    assert time.mktime(time.strptime(started, "%Y-%m-%dT%H:%M:%S")) >= int(finished)
    models = [
        find_run(tmp_path / "trials" / s.trial_id, "ma2c", s.env_id).load_model("cpu") for s in (start, curriculum, scratch)
    ]
    weights = [dict(m.policy.named_parameters()) for m in models]
    # trained on from the start's weights: nearer to them than the trial trained from scratch
    distance = [sum(float((w[k] - weights[0][k]).norm()) for k in weights[0]) for w in weights[1:]]
    assert distance[0] < distance[1]


def test_a_trial_whose_worker_dies_is_retried_from_its_checkpoint(local_ray, tmp_path):
    """SIGKILL the Ray worker of a trial once it has checkpointed: Ray restarts the trial, which
    continues from that checkpoint and finishes."""
    killed: dict[str, int] = {}

    def kill_first_checkpointed_trial() -> None:
        deadline = time.monotonic() + 600  # Ray's start-up and the first evaluation are slow on a busy machine
        while time.monotonic() < deadline and not killed:
            for info in tmp_path.glob("trials/*/trial.json"):
                state = info.parent / "checkpoint" / "state.json"
                if state.is_file() and not (info.parent / "result.json").exists():
                    pid = json.loads(info.read_text())["attempts"][0]["pid"]
                    os.kill(pid, signal.SIGKILL)
                    killed.update(trial=info.parent.name, pid=pid)
                    return
            time.sleep(0.02)

    killer = threading.Thread(target=kill_first_checkpointed_trial, daemon=True)
    killer.start()
    # 4000 AV-steps per trial, a checkpoint at every evaluation (every 400 AV-steps)
    outcome = run_benchmark(log_folder=tmp_path, budget=0.002, eval_every_episodes=2, max_failures=1, **TINY)
    killer.join()
    assert killed, "no trial checkpointed in time"
    assert not outcome.failed and killed["trial"] in outcome.completed
    trial = tmp_path / "trials" / killed["trial"]
    attempts = json.loads((trial / "trial.json").read_text())["attempts"]
    assert len(attempts) == 2 and attempts[1]["pid"] != killed["pid"]
    resumed_at = attempts[1]["resumed_at_timesteps"]
    assert resumed_at > 0
    result = json.loads((trial / "result.json").read_text())
    assert result["num_timesteps"] >= 4000
    timesteps = np.load(trial / "ma2c" / "sb3_marl-LaneChange-density1-v0_1" / "evaluations.npz")["timesteps"]
    assert np.all(np.diff(timesteps) > 0) and resumed_at in timesteps  # one history, continued
    assert (trial / "ma2c" / "sb3_marl-LaneChange-density1-v0_1" / f"resumed_at_{resumed_at}.monitor.csv").is_file()


def test_benchmark_alone_does_not_start_the_full_grid(capsys, tmp_path):
    assert main(["benchmark", "-f", str(tmp_path)]) == 2
    assert "would start the whole paper grid at its full budget" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--grid", "papers"], "argument --grid: invalid choice: 'papers' (choose from 'paper', 'reward'"),
        (["--budget", "0"], "argument --budget: expected a fraction in (0, 1] of the paper's 1M env steps"),
        (["--budget", "1.5"], "argument --budget: expected a fraction in (0, 1]"),
        (["--seeds", "0"], "argument --seeds: expected a finite value >= 1"),
        (["--densities", "4"], "argument --densities: invalid choice: 4"),
        (["--eval-episodes", "100000000"], "argument --eval-episodes: expected a finite value >= 1 and <= 100,000"),
        (["--eval-every", "nan"], "argument --eval-every: expected a finite value >= 1, got nan"),
        (["--eval-every", "inf"], "argument --eval-every: expected a finite value >= 1, got inf"),
        (["status", "--max-failures", "-7"], "argument --max-failures: expected a finite value >= 0 and <= 10,000"),
    ],
)
def test_bad_arguments_are_rejected_before_any_work(argv, message, capsys, tmp_path):
    with pytest.raises(SystemExit) as exit_info:
        main(["benchmark", "-f", str(tmp_path), *argv])
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_bad_api_arguments_and_changed_settings_name_the_field(tiny_benchmark, tmp_path, capsys):
    with pytest.raises(ValueError, match=r"Invalid grid='papers': expected one of \['baselines', 'cadence', 'comfort'"):
        run_benchmark("papers", tmp_path)
    with pytest.raises(ValueError, match=r"Invalid budget=2: expected a fraction in \(0, 1\]"):
        run_benchmark("reward", tmp_path, budget=2)
    with pytest.raises(ValueError, match=r"Invalid density=4: expected one of \[1, 2, 3\]"):
        run_benchmark("reward", tmp_path, densities=(4,))
    assert main(["benchmark", "--grid", "reward", "-f", str(tiny_benchmark), "--budget", "0.5"]) == 2
    assert "holds a benchmark with other settings: budget=0.5 (it has 0.0003)" in capsys.readouterr().err
    assert main(["benchmark", "report", "-f", str(tmp_path / "empty")]) == 2
    assert "No evaluated benchmark trial under" in capsys.readouterr().err


def test_comfort_grid_reports_the_comfort_figure(local_ray, tmp_path):
    outcome = run_benchmark(
        "comfort", tmp_path / "logs", budget=0.0003, seeds=1, densities=(1,), eval_every_episodes=1, verbose=0
    )
    assert sorted(outcome.completed) == ["ma2c_density1_default_seed0", "ma2c_density1_no-comfort_seed0"]
    written = write_report(tmp_path / "logs", tmp_path / "results")
    assert tmp_path / "results" / "comfort.png" in written
    assert (tmp_path / "results" / "comfort.png").stat().st_size > 20_000
    table = (tmp_path / "results" / "paper_table.md").read_text()
    assert "| comfort off | 1 | 1 | 300 |" in table and "(paper 0.582)" in table
    stds = {t.spec.variant: t.final()["acceleration_std"] for t in load_trials(tmp_path / "logs")}
    on, off = stds["default"], stds["no-comfort"]
    assert (
        f"- Here, density 1: acceleration std {on:.3f} m/s² (comfort on) vs {off:.3f} m/s² (comfort off): "
        f"{'lower' if on < off else 'higher'} with comfort (seeds {on:.3f}–{on:.3f} vs {off:.3f}–{off:.3f}: "
        "every seed apart)."
    ) in table  # one seed each: apart unless equal
    trial = next(t for t in load_trials(tmp_path / "logs") if t.spec.variant == "no-comfort")
    trace = acceleration_traces(trial, tmp_path / "logs", seed=10_000)
    assert trace.shape[1] == 3 and 1 <= len(trace) <= 100  # 3 AVs (density 1's largest count), <= 20 s at 5 Hz
    assert np.array_equal(trace, acceleration_traces(trial, tmp_path / "logs", seed=10_000))  # sampled, seeded
    assert np.abs(trace).mean() < 10  # [m/s²]: accelerations, not speeds (25-30 m/s)


def test_cli_attaches_to_an_existing_ray_cluster(local_ray, tmp_path):
    """`sb3-marl benchmark --address` in another process runs its trials on this test's Ray cluster."""
    address = ray.get_runtime_context().gcs_address
    command = [
        sys.executable,
        "-m",
        "sb3_marl",
        "benchmark",
        "--grid",
        "reward",
        "--densities",
        "1",
        "--seeds",
        "1",
        "--budget",
        "0.0003",
        "--eval-every",
        "1",
        "--address",
        address,
        "-f",
        str(tmp_path),
    ]
    completed = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert completed.returncode == 0, completed.stdout[-3000:] + completed.stderr[-3000:]
    assert "2 trials completed, 0 skipped (finished before), 0 failed, 0 stopped unfinished" in completed.stdout
    assert f"Ray cluster at {address}: 2 CPUs, one per trial" in completed.stdout  # this test's, not a new one
    assert len(list(tmp_path.glob("trials/*/result.json"))) == 2


def test_iqm_and_its_bootstrap_interval_follow_rliable():
    from scipy.stats import trim_mean

    from sb3_marl.benchmark.statistics import interquartile_mean, iqm_with_ci

    rng = np.random.default_rng(3)
    for size in (1, 3, 4, 30, 90, 91):
        scores = rng.normal(size=size)
        assert interquartile_mean(scores) == pytest.approx(trim_mean(scores, 0.25))
    scores = rng.normal(10.0, 5.0, size=(3, 30))  # 3 seeds x 30 evaluation episodes
    iqm, low, high = iqm_with_ci(scores, reps=2_000)
    assert iqm == pytest.approx(trim_mean(scores, 0.25, axis=None)) and low < iqm < high
    assert iqm_with_ci(scores, reps=2_000) == (iqm, low, high)  # seeded: reproducible
    # one seed: every stratified resample is that seed, so the interval is the point
    assert iqm_with_ci(scores[:1], reps=200)[1:] == pytest.approx((trim_mean(scores[0], 0.25),) * 2)
    # more seeds, narrower interval
    wide = iqm_with_ci(rng.normal(10.0, 5.0, size=(3, 30)), reps=2_000)
    narrow = iqm_with_ci(rng.normal(10.0, 5.0, size=(30, 30)), reps=2_000)
    assert narrow[2] - narrow[1] < wide[2] - wide[1]


def test_the_clopper_pearson_upper_bound_matches_the_beta_quantile():
    from scipy.stats import beta

    from sb3_marl.benchmark.statistics import clopper_pearson_upper

    assert clopper_pearson_upper(0, 900) == pytest.approx(1 - 0.025 ** (1 / 900))
    for events, trials in ((3, 900), (9, 300), (1, 10), (29, 30)):
        assert clopper_pearson_upper(events, trials) == pytest.approx(beta.ppf(0.975, events + 1, trials - events))
    assert clopper_pearson_upper(5, 5) == 1.0
    with pytest.raises(ValueError, match="events=6, trials=5"):
        clopper_pearson_upper(6, 5)


HELDOUT = Path(__file__).parents[2] / "benchmarks" / "heldout_evaluation.py"


def test_heldout_evaluation_runs_a_supervisor_variant_and_rejects_a_bad_key_before_any_folder(tiny_benchmark, tmp_path):
    def heldout(*argv: str) -> subprocess.CompletedProcess:
        command = [sys.executable, str(HELDOUT), "-f", str(tiny_benchmark), "--densities", "1", "--seeds", "1", *argv]
        return subprocess.run(command, capture_output=True, text=True, timeout=600)

    bad = heldout("--variants", "merge", "--config", "supervisor_joint_serch:True", "-o", str(tmp_path / "bad"))
    assert bad.returncode == 1
    assert "--config: Unknown config key(s) ['supervisor_joint_serch'] for the merge scenario" in bad.stderr
    assert not (tmp_path / "bad").exists()

    out = tmp_path / "joint"
    done = heldout("--episodes", "2", "--config", "supervisor_joint_search:True", "-o", str(out))
    assert done.returncode == 0, done.stderr[-3000:]
    results = json.loads((out / "heldout.json").read_text())
    assert results["protocol"]["config"] == {"supervisor_joint_search": True}
    assert sorted(results["entries"]) == ["idm-mobil_density1", "ma2c_density1_default_seed0"]
    assert results["entries"]["ma2c_density1_default_seed0"]["episodes"] == 2
    assert "on and off, supervisor_joint_search: True;" in (out / "heldout.md").read_text()


def test_benchmark_evaluate_redoes_the_trials_evaluated_under_another_version_of_their_roads_supervisor(tmp_path):
    """Committed trials of both roads, the merge's final evaluation marked as made under the previous
    supervisor version (its version 4 added the emergency brake's release and made
    ``supervisor_joint_search`` the default), the lane change's as made under its current one:
    ``benchmark evaluate`` redoes the merge trial's and leaves the lane change's; a second call
    redoes nothing."""
    from sb3_marl.envs.config import LANE_CHANGE, MERGE, supervisor_version

    versions = {scenario: supervisor_version(None, scenario) for scenario in (LANE_CHANGE, MERGE)}

    grid = Path(__file__).resolve().parents[2] / "results" / "paper-grid"
    copy = tmp_path / "grid"
    (copy / "trials").mkdir(parents=True)
    (copy / "benchmark.json").write_text((grid / "benchmark.json").read_text())
    trials = {LANE_CHANGE: "ma2c_density1_default_seed0", MERGE: "ma2c_density1_merge_seed0"}
    for scenario, name in trials.items():
        subprocess.run(["cp", "-r", str(grid / "trials" / name), str(copy / "trials" / name)], check=True)
        result = json.loads((copy / "trials" / name / "result.json").read_text())
        assert result["paper_evaluation"]["supervisor_version"] == {LANE_CHANGE: 5, MERGE: 4}[scenario]  # as committed
        result["paper_evaluation"]["supervisor_version"] = versions[scenario] - (scenario == MERGE)
        (copy / "trials" / name / "result.json").write_text(json.dumps(result))
    stamp = {name: (copy / "trials" / name / "result.json").stat().st_mtime_ns for name in trials.values()}
    assert main(["benchmark", "evaluate", "-f", str(copy)]) == 0
    redone = json.loads((copy / "trials" / trials[MERGE] / "result.json").read_text())["paper_evaluation"]
    committed = json.loads((grid / "trials" / trials[MERGE] / "result.json").read_text())["paper_evaluation"]
    assert redone["supervisor_version"] == versions[MERGE] == 4
    assert redone["return_mean"] == pytest.approx(committed["return_mean"], abs=1e-9)
    assert redone["traffic"]["flow_veh_h"] > 0 and "traffic" in redone["supervisor_off"]  # with the traffic view
    assert (copy / "trials" / trials[LANE_CHANGE] / "result.json").stat().st_mtime_ns == stamp[trials[LANE_CHANGE]]
    stamp = (copy / "trials" / trials[MERGE] / "result.json").stat().st_mtime_ns
    assert main(["benchmark", "evaluate", "-f", str(copy)]) == 0
    assert (copy / "trials" / trials[MERGE] / "result.json").stat().st_mtime_ns == stamp


def test_status_counts_the_seeds_the_folder_holds(capsys):
    """The committed grid holds seeds 0-2: status without --seeds lists all 81 trials, not 54."""
    grid = Path(__file__).resolve().parents[2] / "results" / "paper-grid"
    assert main(["benchmark", "status", "-f", str(grid)]) == 0
    assert "81 of 81 trials finished" in capsys.readouterr().out
    assert main(["benchmark", "status", "-f", str(grid), "--seeds", "2"]) == 0
    assert "54 of 54 trials finished" in capsys.readouterr().out
