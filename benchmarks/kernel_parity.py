"""Parity of the compiled kernel with highway-env's classes over many seeded episodes.

For each density and action mix (uniform random, mostly-IDLE "cruise", and cruise with the safety
supervisor on, whose episodes run to the time limit), the same seeded episodes run under
:data:`~sb3_marl.sim.simulator.STOCK` (highway-env's own classes, frame by frame) and
:data:`~sb3_marl.sim.simulator.COMPILED` (the default); prints the largest
state and observation differences, the episodes whose events (crashes, lane changes, HDV lane
decisions, lengths) differ, and what the episodes exercised. ``name: value unit`` lines.

    python benchmarks/kernel_parity.py [--episodes 200] [--densities 1 2 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

from sb3_marl.envs import DENSITIES, ENV_IDS
from sb3_marl.sim.simulator import COMPILED, STOCK

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "envs"))  # the parity helpers (test support)
from parity import compare

MIXES = {"uniform": ("uniform", {}), "cruise": ("cruise", {}), "cruise_supervised": ("cruise", {"safety_supervisor": True})}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=200, help="seeded episodes per density and mix")
    parser.add_argument("--densities", type=int, nargs="+", default=sorted(DENSITIES))
    args = parser.parse_args()
    for density in args.densities:
        for name, (policy, config) in MIXES.items():
            start = time.perf_counter()
            result = compare(STOCK, COMPILED, ENV_IDS[density], range(args.episodes), policy, **config)
            tag = f"density{density}_{name}"
            print(f"{tag}_episodes: {result.episodes}")
            print(f"{tag}_different_outcomes: {len(result.different_outcomes)} {result.different_outcomes[:10]}")
            print(f"{tag}_max_state_difference: {result.max_state_difference:.3g} m|rad|m/s")
            print(f"{tag}_max_observation_difference: {result.max_observation_difference:.3g}")
            print(f"{tag}_crashes: {result.crashes}")
            print(f"{tag}_hdv_lane_changes: {result.hdv_lane_changes}")
            print(f"{tag}_wall_time: {time.perf_counter() - start:.1f} s", flush=True)


if __name__ == "__main__":
    main()
