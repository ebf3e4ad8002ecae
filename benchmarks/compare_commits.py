"""Speed of this working tree against an earlier commit, side by side in one run.

Checks ``--base`` out into a temporary git worktree and runs, for each tree in turn (the same
machine, one process at a time), its own ``benchmarks/env_throughput.py`` (the env alone with
resets, vs stock highway-v0) and ``benchmarks/train_throughput.py`` (the ``--algos``' training
throughput, ``dummy`` VecEnv, one torch thread), ``--rounds`` times, the trees alternating, and
prints ``name: base current current/base`` lines of the medians for every number both trees report
(a VM's timings move 10-30 % from one minute to the next; alternating rounds share that noise).

    python benchmarks/compare_commits.py --base ecd13c3 [--densities 1 3] [--steps 2000] [--timesteps 20000]
        [--algos ma2c] [--rounds 1] [--only env train]
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LINE = re.compile(r"^(\S+): ([-+0-9.eE]+) (.+)$")


def measure(tree: Path, args: argparse.Namespace) -> dict[str, tuple[float, str]]:
    """``name -> (value, unit)`` of the two benchmarks run from ``tree``'s own code."""
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1"}
    densities = [str(d) for d in args.densities]
    commands = {
        "env": ["benchmarks/env_throughput.py", "--steps", str(args.steps), "--densities", *densities],
        "train": ["benchmarks/train_throughput.py", "--algos", *args.algos, "--vec-envs", "dummy", "--densities", *densities,
                  "--timesteps", str(args.timesteps)],
    }  # fmt: skip
    # a short first run fills the tree's numba cache, so that no measurement includes compiling
    subprocess.run([sys.executable, commands["env"][0], "--steps", "50"], cwd=tree, env=env, check=True, capture_output=True)
    results = {}
    for command in (commands[name] for name in args.only):
        print(f"# {tree}: {' '.join(command)}", file=sys.stderr, flush=True)
        out = subprocess.run([sys.executable, *command], cwd=tree, env=env, check=True, capture_output=True, text=True)
        for line in out.stdout.splitlines():
            match = LINE.match(line)
            if match:
                results[match[1]] = (float(match[2]), match[3])
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, help="the earlier commit (any git revision)")
    parser.add_argument("--densities", type=int, nargs="+", default=[1, 3])
    parser.add_argument("--steps", type=int, default=2000, help="env steps per env measurement")
    parser.add_argument("--timesteps", type=int, default=20_000, help="timed AV-steps per training measurement")
    parser.add_argument("--algos", nargs="+", default=["ma2c"], help="the learners whose training is timed")
    parser.add_argument("--rounds", type=int, default=1, help="rounds of both trees, alternating; medians reported")
    parser.add_argument("--only", nargs="+", choices=["env", "train"], default=["env", "train"], help="the benchmarks run")
    args = parser.parse_args()
    runs: dict[str, list[dict[str, tuple[float, str]]]] = {"base": [], "current": []}
    with tempfile.TemporaryDirectory() as scratch:
        base_tree = Path(scratch) / "base"
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(base_tree), args.base], cwd=REPO, check=True, capture_output=True
        )
        try:
            for _ in range(args.rounds):
                runs["base"].append(measure(base_tree, args))
                runs["current"].append(measure(REPO, args))
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base_tree)], cwd=REPO, check=True)
    base, current = (median_of(runs[tree]) for tree in ("base", "current"))
    print(f"base: {args.base} (medians of {args.rounds} round(s))")
    for name, (value, unit) in current.items():
        if name in base and base[name][0]:
            print(f"{name}: {base[name][0]:g} {value:g} {value / base[name][0]:.2f}x ({unit})")


def median_of(rounds: list[dict[str, tuple[float, str]]]) -> dict[str, tuple[float, str]]:
    """Each number's median over the rounds that report it, with its unit."""
    names = [name for name in rounds[0] if all(name in r for r in rounds)]
    return {name: (statistics.median(r[name][0] for r in rounds), rounds[0][name][1]) for name in names}


if __name__ == "__main__":
    main()
