"""Training throughput of the learners with their zoo configs, and the projected wall time of a paper run.

For each algorithm x density x VecEnv backend: build the parameter-sharing VecEnv and the model
exactly as ``sb3-marl train`` does (zoo config, default copies: one per AV count of the density,
or ``--copies``), train ``--warmup`` AV-steps (past DQN's ``learning_starts``, so that gradient
steps are counted), then time ``--timesteps`` more. Env steps are counted per scenario copy: one
VecEnv step steps every copy once. The paper trains for 1M env steps; ``projected_1M_env_steps``
is 1e6 divided by the measured env-steps/s. Prints ``name: value unit`` lines.

``--grid paper`` instead measures every curve of the paper's grid (each algorithm and variant at
each density, ``dummy`` backend) and projects the grid's wall time at the full budget: the sum
of its trials' projected times (``--seeds`` per curve) over ``--workers`` concurrent trials (one
core each), plus their evaluations (3 episodes every 200 training episodes: 1.5 % more steps).

    python benchmarks/train_throughput.py [--algos ma2c mappo madqn maacktr] [--densities 1 2 3]
        [--vec-envs dummy subproc] [--copies 3 6] [--timesteps 20000] [--warmup 2000]
    python benchmarks/train_throughput.py --grid paper [--seeds 3] [--workers 2]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch

from sb3_marl.algos import ALGOS
from sb3_marl.algos.common.policies import unchecked_distributions
from sb3_marl.benchmark.grid import PAPER_EVAL_EPISODES, PAPER_EVAL_EVERY_EPISODES, make_grid
from sb3_marl.envs import ENV_IDS
from sb3_marl.runs.hyperparams import load_hyperparams, merge_hyperparams
from sb3_marl.runs.training import make_model, make_venv

PAPER_ENV_STEPS = 1_000_000


def measure(
    algo: str, density: int, vec_env: str, timesteps: int, warmup: int, seed: int, overrides: dict | None = None
) -> dict[str, float]:
    """AV-steps/s and env-steps/s of ``timesteps`` AV-steps of training after ``warmup`` AV-steps,
    with ``overrides`` of the zoo config (a grid variant, ``n_copies``)."""
    env_id = ENV_IDS[density]
    hyperparams = merge_hyperparams(load_hyperparams(algo, env_id), overrides)
    venv = make_venv(env_id, hyperparams, seed=seed, vec_backend=vec_env)
    try:
        model = make_model(algo, venv, hyperparams, seed=seed)
        warmup = max(warmup, int(hyperparams.get("learning_starts", 0)) + venv.num_envs)
        with unchecked_distributions():
            model.learn(warmup)
            start_steps, start = model.num_timesteps, time.perf_counter()
            model.learn(timesteps, reset_num_timesteps=False)
            seconds = time.perf_counter() - start
    finally:
        venv.close()
    av_steps = model.num_timesteps - start_steps
    env_steps = av_steps // venv.num_envs * len(venv.unwrapped.n_avs)  # VecEnv steps x copies
    return {"av_steps_per_s": av_steps / seconds, "env_steps_per_s": env_steps / seconds}


def project_grid(grid: str, seeds: int, workers: int, timesteps: int, warmup: int, seed: int) -> None:
    """Measure each curve of ``grid`` once per density and project the grid's full-budget wall time."""
    total = 0.0
    curves = make_grid(grid, seeds=1)
    for spec in curves:
        result = measure(spec.algo, spec.density, "dummy", timesteps, warmup, seed, spec.hyperparams)
        minutes = PAPER_ENV_STEPS / result["env_steps_per_s"] / 60 * (1 + PAPER_EVAL_EPISODES / PAPER_EVAL_EVERY_EPISODES)
        total += minutes * seeds
        print(f"{spec.algo}_{spec.variant}_density{spec.density}_env_steps: {result['env_steps_per_s']:.0f} env-steps/s")
        print(f"{spec.algo}_{spec.variant}_density{spec.density}_projected_trial: {minutes:.1f} min", flush=True)
    print(f"{grid}_grid_trials: {len(curves) * seeds}")
    print(f"{grid}_grid_projected_core_time: {total / 60:.1f} h")
    print(f"{grid}_grid_projected_wall_time_{workers}_workers: {total / 60 / workers:.1f} h")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algos", nargs="+", default=["ma2c", "mappo", "madqn", "maacktr"], choices=sorted(ALGOS))
    parser.add_argument("--densities", type=int, nargs="+", default=sorted(ENV_IDS), choices=sorted(ENV_IDS))
    parser.add_argument("--vec-envs", nargs="+", default=["dummy", "subproc"], choices=["dummy", "subproc"])
    parser.add_argument("--copies", type=int, nargs="+", default=[None], help="scenario copies (default: the zoo config's)")
    parser.add_argument("--timesteps", type=int, default=20_000, help="timed AV-steps per measurement")
    parser.add_argument("--warmup", type=int, default=2_000, help="untimed AV-steps first")
    parser.add_argument("--torch-threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--grid", default=None, help="project this benchmark grid's wall time instead (e.g. paper)")
    parser.add_argument("--seeds", type=int, default=3, help="--grid: seeds per curve")
    parser.add_argument("--workers", type=int, default=2, help="--grid: concurrent trials, one core each")
    args = parser.parse_args()
    torch.set_num_threads(args.torch_threads)
    print(f"cpu_cores: {os.cpu_count()}")
    if args.grid:
        project_grid(args.grid, args.seeds, args.workers, args.timesteps, args.warmup, args.seed)
        return
    for algo in args.algos:
        for density in args.densities:
            for vec_env in args.vec_envs:
                for copies in args.copies:
                    overrides = {} if copies is None else {"n_copies": copies}
                    result = measure(algo, density, vec_env, args.timesteps, args.warmup, args.seed, overrides)
                    tag = f"{algo}_density{density}_{vec_env}" + ("" if copies is None else f"_{copies}copies")
                    print(f"{tag}_av_steps: {result['av_steps_per_s']:.0f} AV-steps/s")
                    print(f"{tag}_env_steps: {result['env_steps_per_s']:.0f} env-steps/s")
                    minutes = PAPER_ENV_STEPS / result["env_steps_per_s"] / 60
                    print(f"{tag}_projected_1M_env_steps: {minutes:.1f} min", flush=True)


if __name__ == "__main__":
    main()
