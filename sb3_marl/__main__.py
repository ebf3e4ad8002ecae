"""Main job until training lands: drive the scenario with reference policies and print metrics.

    python -m sb3_marl [--density 1] [--episodes 20] [--seed 0] [--out logs/scenario_baselines.md]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym

from sb3_marl.baselines import BASELINES
from sb3_marl.envs import DENSITIES, ENV_IDS
from sb3_marl.evaluation import run_episodes, summarize

COLUMNS = (
    ("policy", "{}"), ("n_avs", "{}"), ("return", "{}"), ("collision rate", "{:.2f}"), ("mean speed [m/s]", "{:.2f}"),
    ("mean headway [m]", "{:.1f}"), ("accel. std [m/s²]", "{:.3f}"), ("lane changes/ep", "{:.2f}"),
    ("steps/ep", "{:.1f}"),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--density", type=int, choices=sorted(DENSITIES), default=1)
    parser.add_argument("--episodes", type=int, default=20, help="episodes per policy and AV count")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("logs/scenario_baselines.md"))
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")

    lo, hi = DENSITIES[args.density]["avs"]
    rows, results = [], []
    start = time.perf_counter()
    for name, policy_class in BASELINES.items():
        for n_avs in range(lo, hi + 1):
            env = gym.make(ENV_IDS[args.density], config={"n_avs": n_avs}).unwrapped
            summary = summarize(run_episodes(env, policy_class(), args.episodes, seed=args.seed))
            results.append({"policy": name, "n_avs": n_avs, **summary})
            rows.append((
                name, n_avs, f"{summary['return_mean']:.2f} ± {summary['return_std']:.2f}", summary["collision_rate"],
                summary["speed_mean"], summary["headway_mean"], summary["acceleration_std"],
                summary["lane_changes_per_episode"], summary["length_mean"],
            ))
    lines = [
        f"Scenario {ENV_IDS[args.density]}: {args.episodes} episodes per row, seeds {args.seed}..{args.seed + args.episodes - 1}",
        "",
        "| " + " | ".join(title for title, _ in COLUMNS) + " |",
        "|" + "---|" * len(COLUMNS),
        *("| " + " | ".join(fmt.format(v) for (_, fmt), v in zip(COLUMNS, row)) + " |" for row in rows),
    ]
    table = "\n".join(lines)
    print(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(table + "\n")
    args.out.with_suffix(".json").write_text(json.dumps(results, indent=2))
    print(f"\nwrote {args.out} and {args.out.with_suffix('.json')} in {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
