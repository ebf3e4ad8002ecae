"""Training throughput of the learners with their zoo configs, and the projected wall time of a paper run.

For each algorithm x density x VecEnv backend: build the parameter-sharing VecEnv and the model
exactly as ``sb3-marl train`` does (zoo config, default copies: one per AV count of the density),
train ``--warmup`` AV-steps (past DQN's ``learning_starts``, so that gradient steps are counted),
then time ``--timesteps`` more. Env steps are counted per scenario copy: one VecEnv step steps
every copy once. The paper trains for 1M env steps; ``projected_1M_env_steps`` is 1e6 divided by
the measured env-steps/s. Prints ``name: value unit`` lines.

    python benchmarks/train_throughput.py [--algos ma2c mappo madqn] [--densities 1 2 3]
        [--vec-envs dummy subproc] [--timesteps 20000] [--warmup 2000]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch

from sb3_marl.algos import ALGOS
from sb3_marl.envs import ENV_IDS
from sb3_marl.hyperparams import load_hyperparams
from sb3_marl.policies import unchecked_distributions
from sb3_marl.training import make_model, make_venv

PAPER_ENV_STEPS = 1_000_000


def measure(algo: str, density: int, vec_env: str, timesteps: int, warmup: int, seed: int) -> dict[str, float]:
    """AV-steps/s and env-steps/s of ``timesteps`` AV-steps of training after ``warmup`` AV-steps."""
    env_id = ENV_IDS[density]
    hyperparams = load_hyperparams(algo, env_id)
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algos", nargs="+", default=["ma2c", "mappo", "madqn"], choices=sorted(ALGOS))
    parser.add_argument("--densities", type=int, nargs="+", default=sorted(ENV_IDS), choices=sorted(ENV_IDS))
    parser.add_argument("--vec-envs", nargs="+", default=["dummy", "subproc"], choices=["dummy", "subproc"])
    parser.add_argument("--timesteps", type=int, default=20_000, help="timed AV-steps per measurement")
    parser.add_argument("--warmup", type=int, default=2_000, help="untimed AV-steps first")
    parser.add_argument("--torch-threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(args.torch_threads)
    print(f"cpu_cores: {os.cpu_count()}")
    for algo in args.algos:
        for density in args.densities:
            for vec_env in args.vec_envs:
                result = measure(algo, density, vec_env, args.timesteps, args.warmup, args.seed)
                tag = f"{algo}_density{density}_{vec_env}"
                print(f"{tag}_av_steps: {result['av_steps_per_s']:.0f} AV-steps/s")
                print(f"{tag}_env_steps: {result['env_steps_per_s']:.0f} env-steps/s")
                print(f"{tag}_projected_1M_env_steps: {PAPER_ENV_STEPS / result['env_steps_per_s'] / 60:.1f} min", flush=True)


if __name__ == "__main__":
    main()
