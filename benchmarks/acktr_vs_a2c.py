"""Sample efficiency of ACKTR vs A2C: same env steps, same seeds, learning curves and wall time.

Two tasks:

- ``cartpole``: CartPole-v1, 16 envs, 16 steps per update (the same batches), no entropy bonus;
  ACKTR at learning rate 0.1 (the test's setting), A2C with SB3's default RMSprop at 7e-4.
- ``lanechange``: density 1 of our scenario with the zoo configs ``maacktr.yml`` and ``ma2c.yml``
  (the same rollouts, losses and network; only the optimiser differs).

``--evaluations`` times per run, at even intervals of env steps, each model plays
``--eval-episodes`` seeded deterministic episodes (CartPole seeds 100...; the scenario's seeds
10000..., the paper's metric). Prints one line per evaluation and ``name: value unit`` lines for
the final returns and wall times.

    python benchmarks/acktr_vs_a2c.py [--task cartpole lanechange] [--seeds 0 1] [--cartpole-steps 80000]
        [--lanechange-steps 100000] [--evaluations 4] [--eval-episodes 10]
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import A2C
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_marl.algos.acktr import ACKTR
from sb3_marl.algos.common.policies import model_policy, unchecked_distributions
from sb3_marl.envs import ENV_IDS
from sb3_marl.evaluation import evaluate_on_density
from sb3_marl.runs.hyperparams import load_hyperparams
from sb3_marl.runs.training import make_model, make_venv


def cartpole_learner(algo: str, seed: int) -> tuple[BaseAlgorithm, Callable[[BaseAlgorithm, int], float], int]:
    env = make_vec_env("CartPole-v1", n_envs=16, seed=seed)
    if algo == "acktr":
        model = ACKTR("MlpPolicy", env, learning_rate=0.1, n_steps=16, ent_coef=0.0, seed=seed, device="cpu")
    else:
        model = A2C("MlpPolicy", env, n_steps=16, ent_coef=0.0, seed=seed, device="cpu")

    def score(model: BaseAlgorithm, episodes: int) -> float:
        eval_env = gym.make("CartPole-v1")
        eval_env.reset(seed=100)
        returns, _ = evaluate_policy(model, eval_env, n_eval_episodes=episodes, return_episode_rewards=True)
        return float(np.mean(returns))

    return model, score, 1  # one env step per SB3 timestep


def lanechange_learner(algo: str, seed: int) -> tuple[BaseAlgorithm, Callable[[BaseAlgorithm, int], float], int]:
    name = "maacktr" if algo == "acktr" else "ma2c"
    env_id = ENV_IDS[1]
    hyperparams = load_hyperparams(name, env_id)
    venv = make_venv(env_id, hyperparams, seed=seed)
    model = make_model(name, venv, hyperparams, seed=seed)

    def score(model: BaseAlgorithm, episodes: int) -> float:
        return evaluate_on_density(model_policy(model), env_id, episodes, seed=10_000)["return_mean"]

    return model, score, venv.num_envs // len(venv.unwrapped.n_avs)  # AV-steps per env step


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", nargs="+", default=["cartpole", "lanechange"], choices=["cartpole", "lanechange"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--cartpole-steps", type=int, default=80_000, help="env steps")
    parser.add_argument("--lanechange-steps", type=int, default=100_000, help="env steps (1M in the paper)")
    parser.add_argument("--evaluations", type=int, default=4, help="evaluations per run, evenly spaced")
    parser.add_argument("--eval-episodes", type=int, default=10)
    args = parser.parse_args()
    torch.set_num_threads(1)
    for task in args.task:
        env_steps = args.cartpole_steps if task == "cartpole" else args.lanechange_steps
        build = cartpole_learner if task == "cartpole" else lanechange_learner
        for algo in ("acktr", "a2c"):
            finals, walls = [], []
            for seed in args.seeds:
                model, score, timesteps_per_env_step = build(algo, seed)
                start, curve = time.perf_counter(), []
                chunk = env_steps * timesteps_per_env_step // args.evaluations
                with unchecked_distributions():
                    for _ in range(args.evaluations):
                        model.learn(chunk, reset_num_timesteps=False)
                        curve.append(score(model, args.eval_episodes))
                walls.append(time.perf_counter() - start)
                finals.append(curve[-1])
                steps = [env_steps * (k + 1) // args.evaluations for k in range(args.evaluations)]
                print(f"{task} {algo} seed {seed}: " + " ".join(f"{s}:{r:.1f}" for s, r in zip(steps, curve)), flush=True)
            print(f"{task}_{algo}_final_return: {np.mean(finals):.2f} +- {np.std(finals):.2f} (over seeds {args.seeds})")
            print(f"{task}_{algo}_wall_time: {np.mean(walls):.0f} s per run (incl. evaluations)", flush=True)


if __name__ == "__main__":
    main()
