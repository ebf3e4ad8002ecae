"""How safe the safety supervisor keeps simple policies, per density and AV count (one process).

Each policy (``random``: uniform over each AV's available meta-actions, from a generator seeded with the
episode's seed, so every episode is the same whatever the others did;
``idle``: always IDLE) drives ``--episodes`` seeded episodes at every AV count of each density
(the largest included) with the safety supervisor on; prints, per count, the share of episodes
with a crash, the supervisor's interventions per AV-step, and for each crash the step it happened
at and the AVs' proposed and executed meta-actions of that step. Run it on two commits to compare
supervisor versions on the same episodes.

    python benchmarks/supervisor_safety.py [--episodes 1000] [--densities 1 2 3] [--policies random idle] [--seed 200000]

``--scenario merge`` runs the on-ramp merge (its ``--priority``: the supervisor's order of service);
``--config key:value ...`` sets env config keys (e.g. ``supervisor_min_gap:3.0``), as ``--env-kwargs``.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from sb3_marl.cli.common import StoreHyperparams
from sb3_marl.envs import ENV_IDS, MERGE_ENV_IDS, make_scenario
from sb3_marl.envs.config import LANE_CHANGE, MERGE, SCENARIO_DENSITIES, SUPERVISOR_PRIORITIES
from sb3_marl.evaluation import run_episodes, summarize
from sb3_marl.evaluation.baselines import CruisePolicy


class MaskedRandomPolicy:
    """Each AV's meta-action drawn uniformly among its available ones, from a seeded generator."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def __call__(self, env, obs: np.ndarray) -> np.ndarray:
        return np.array([self.rng.choice(np.flatnonzero(mask)) for mask in env.action_masks()])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--densities", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--policies", nargs="+", default=["random", "idle"], choices=["random", "idle"])
    parser.add_argument("--seed", type=int, default=200_000, help="first episode seed (default: 200000)")
    parser.add_argument("--n-avs", type=int, nargs="+", default=None, help="only these AV counts (default: all)")
    parser.add_argument("--no-rear-avs", action="store_true", help="supervisor_rear_avs: false (see the config)")
    parser.add_argument("--scenario", default=LANE_CHANGE, choices=[LANE_CHANGE, MERGE])
    parser.add_argument("--priority", default=None, choices=SUPERVISOR_PRIORITIES, help="merge only: supervisor_priority")
    parser.add_argument(
        "--config", nargs="+", default={}, action=StoreHyperparams, metavar="KEY:VALUE", help="env config keys to set"
    )
    args = parser.parse_args()
    overrides = args.config
    ids = MERGE_ENV_IDS if args.scenario == MERGE else ENV_IDS
    print(
        f"scenario {args.scenario}"
        + (f", supervisor_priority {args.priority}" if args.priority else "")
        + "".join(f", {key} {value}" for key, value in overrides.items()),
        flush=True,
    )
    for density in args.densities:
        low, high = SCENARIO_DENSITIES[args.scenario][density]["avs"]
        for n_avs in [n for n in range(low, high + 1) if args.n_avs is None or n in args.n_avs]:
            for name in args.policies:
                start = time.perf_counter()
                config = {"safety_supervisor": True, "n_avs": n_avs, "supervisor_rear_avs": not args.no_rear_avs}
                if args.priority is not None:
                    config["supervisor_priority"] = args.priority
                config.update(overrides)
                env = make_scenario(ids[density], config)
                crashes: list[str] = []
                records = []
                for episode in range(args.episodes):
                    seed = args.seed + episode

                    def on_step(env, info, seed=seed, crashes=crashes) -> None:
                        if info["step"] and info["crashed"].any():
                            crashes.append(
                                f"    seed {seed} step {info['step']}: crashed {np.flatnonzero(info['crashed']).tolist()}, "
                                f"proposed {info['proposed_action'].tolist()}, executed {info['executed_action'].tolist()}"
                            )

                    policy = MaskedRandomPolicy(seed) if name == "random" else CruisePolicy()
                    records += run_episodes(env, policy, 1, seed, on_step)
                summary = summarize(records)
                print(
                    f"density {density}, {n_avs} AVs, {name}: crash_rate {summary['collision_rate']:.4f} "
                    f"({len(crashes)} of {args.episodes} episodes), interventions_per_av_step "
                    f"{summary['intervention_rate']:.4f}, wall {time.perf_counter() - start:.0f} s",
                    flush=True,
                )
                for line in crashes:
                    print(line, flush=True)


if __name__ == "__main__":
    main()
