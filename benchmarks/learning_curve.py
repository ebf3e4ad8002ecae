"""Train a learner from its zoo config and print a seeded evaluation every ``--eval-every`` AV-steps.

    python benchmarks/learning_curve.py --algo ma2c --density 1 --timesteps 400000 [--eval-every 50000]

Each evaluation plays ``--eval-episodes`` episodes (seeds 10000..., cycling through the density's
AV counts) with actions sampled from the policy (the authors' protocol), the zoo config's scenario
(safety supervisor on), and prints the paper's metric (mean ± std episode return),
collision rate, mean speed and acceleration std; the last lines give the wall time.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch

from sb3_marl.algos.common.policies import model_policy
from sb3_marl.envs import ENV_IDS, av_steps_per_env_step
from sb3_marl.evaluation import evaluate_on_density
from sb3_marl.runs.hyperparams import load_hyperparams
from sb3_marl.runs.training import make_model, make_venv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", default="ma2c")
    parser.add_argument("--density", type=int, default=1, choices=sorted(ENV_IDS))
    parser.add_argument("--timesteps", type=int, default=400_000, help="AV-steps (SB3 timesteps)")
    parser.add_argument("--eval-every", type=int, default=50_000)
    parser.add_argument("--eval-episodes", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--vec-env", default="dummy", choices=["dummy", "subproc"])
    parser.add_argument("-c", "--conf-file", default=None, help="YAML instead of zoo_configs/<algo>.yml")
    args = parser.parse_args()
    torch.set_num_threads(1)

    env_id = ENV_IDS[args.density]
    hyperparams = load_hyperparams(args.algo, env_id, path=args.conf_file)
    venv = make_venv(env_id, hyperparams, seed=args.seed, vec_backend=args.vec_env)
    model = make_model(args.algo, venv, hyperparams, seed=args.seed)
    config = hyperparams.get("env_config")
    av_steps = av_steps_per_env_step(env_id, config, hyperparams.get("n_copies"))
    start = time.perf_counter()
    while model.num_timesteps < args.timesteps:
        model.learn(args.eval_every, reset_num_timesteps=False)
        summary = evaluate_on_density(model_policy(model), env_id, args.eval_episodes, seed=10_000, config=config)
        env_steps = round(model.num_timesteps / av_steps)
        print(
            f"{args.algo}_{env_id}_step{model.num_timesteps}: env_steps={env_steps} "
            f"return={summary['return_mean']:.2f}±{summary['return_std']:.2f} "
            f"collision_rate={summary['collision_rate']:.2f} speed={summary['speed_mean']:.2f}m/s "
            f"accel_std={summary['acceleration_std']:.3f}m/s2 lane_changes={summary['lane_changes_per_episode']:.2f} "
            f"wall={time.perf_counter() - start:.0f}s",
            flush=True,
        )
    print(f"wall_time: {time.perf_counter() - start:.0f} s")
    venv.close()


if __name__ == "__main__":
    main()
