"""Benchmark-grid throughput on Ray Tune: trials per hour with 1, 2, ... concurrent trials.

Runs the same small grid (default: the ``reward`` experiment, 2 seeds x the chosen densities,
MA2C, budget 0.005 = 5,000 env steps per trial, evaluated every 10 training episodes) once per
worker count, each in a fresh log folder on one local Ray instance with as many CPUs as the
largest worker count, and prints ``name: value unit`` lines. The wall time counts from Tuner
start to the last trial's end (Ray's start-up excluded, trial start-up included).

    python benchmarks/grid_scaling.py                   # 1 and 2 workers (this 2-core machine)
    python benchmarks/grid_scaling.py --workers 1 4 8 16 --densities 1 2 3
"""

from __future__ import annotations

import argparse
import os
import tempfile

import ray

from sb3_marl.benchmark import make_grid
from sb3_marl.benchmark.runner import run_benchmark


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="concurrent trials to compare")
    parser.add_argument("--grid", default="reward")
    parser.add_argument("--densities", type=int, nargs="+", default=[1])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--budget", type=float, default=0.005, help="fraction of 1M env steps per trial")
    parser.add_argument("--eval-every", type=float, default=10, help="training episodes between evaluations")
    args = parser.parse_args()

    n_trials = len(make_grid(args.grid, tuple(args.densities), args.seeds))
    print(
        f"grid {args.grid!r}, densities {args.densities}, {args.seeds} seeds: {n_trials} trials of "
        f"{args.budget * 1e6:,.0f} env steps; {os.cpu_count()} cores"
    )
    ray.init(num_cpus=max(args.workers), include_dashboard=False, configure_logging=False, log_to_driver=False)
    rates = {}
    try:
        for workers in args.workers:
            with tempfile.TemporaryDirectory() as folder:
                outcome = run_benchmark(
                    args.grid,
                    folder,
                    args.budget,
                    args.seeds,
                    tuple(args.densities),
                    args.eval_every,
                    max_concurrent=workers,
                    verbose=0,
                )
            assert not outcome.failed, outcome.failed
            rates[workers] = len(outcome.completed) / outcome.wall_time_s * 3600
            print(f"grid_wall_time_{workers}_workers: {outcome.wall_time_s:.1f} s")
            print(f"trials_per_hour_{workers}_workers: {rates[workers]:.0f} trials/h")
    finally:
        ray.shutdown()
    base = min(rates)
    for workers, rate in rates.items():
        if workers != base:
            print(f"speedup_{workers}_vs_{base}_workers: {rate / rates[base]:.2f}x")


if __name__ == "__main__":
    main()
