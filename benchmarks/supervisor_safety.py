"""How safe the safety supervisor keeps a random masked policy, per density (one process).

A seeded random policy over each AV's available meta-actions drives ``--episodes`` seeded episodes
per density (cycling through the density's AV counts) with the safety supervisor on; prints the
share of episodes with a crash and the supervisor's interventions per AV-step. Run it on two
commits to compare supervisor versions on the same episodes.

    python benchmarks/supervisor_safety.py [--episodes 1000] [--densities 1 2 3] [--seed 200000]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from sb3_marl.envs import DENSITIES, ENV_IDS
from sb3_marl.evaluation import evaluation_records, summarize


class MaskedRandomPolicy:
    """Each AV's meta-action drawn uniformly among its available ones, from a seeded generator."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def __call__(self, env, obs: np.ndarray) -> np.ndarray:
        return np.array([self.rng.choice(np.flatnonzero(mask)) for mask in env.action_masks()])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--densities", type=int, nargs="+", default=list(DENSITIES))
    parser.add_argument("--seed", type=int, default=200_000, help="first episode seed (default: 200000)")
    args = parser.parse_args()
    for density in args.densities:
        start = time.perf_counter()
        records = evaluation_records(MaskedRandomPolicy(args.seed), ENV_IDS[density], args.episodes, args.seed,
                                     {"safety_supervisor": True})
        summary = summarize(records)
        crashes = sum(r.crashed for r in records)
        print(f"density {density}: crash_rate {summary['collision_rate']:.4f} ({crashes} of {args.episodes} episodes), "
              f"interventions_per_av_step {summary['intervention_rate']:.4f}, "
              f"wall {time.perf_counter() - start:.0f} s", flush=True)


if __name__ == "__main__":
    main()
