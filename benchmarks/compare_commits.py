"""Speed of this working tree against an earlier commit, side by side in one run.

Checks ``--base`` out into a temporary git worktree and runs, for each tree in turn (the same
machine, one process at a time), its own ``benchmarks/env_throughput.py`` (the env alone with
resets, vs stock highway-v0) and ``benchmarks/train_throughput.py`` (MA2C training throughput,
``dummy`` VecEnv, one torch thread). Prints ``name: base current current/base`` lines for every
number both trees report.

    python benchmarks/compare_commits.py --base ecd13c3 [--densities 1 3] [--steps 2000] [--timesteps 20000]
"""

from __future__ import annotations

import argparse
import os
import re
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
    commands = [
        ["benchmarks/env_throughput.py", "--steps", str(args.steps), "--densities", *densities],
        ["benchmarks/train_throughput.py", "--algos", "ma2c", "--vec-envs", "dummy", "--densities", *densities,
         "--timesteps", str(args.timesteps)],
    ]  # fmt: skip
    # a short first run fills the tree's numba cache, so that no measurement includes compiling
    subprocess.run([sys.executable, commands[0][0], "--steps", "50"], cwd=tree, env=env, check=True, capture_output=True)
    results = {}
    for command in commands:
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
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        base_tree = Path(scratch) / "base"
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(base_tree), args.base], cwd=REPO, check=True, capture_output=True
        )
        try:
            base = measure(base_tree, args)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base_tree)], cwd=REPO, check=True)
    current = measure(REPO, args)
    print(f"base: {args.base}")
    for name, (value, unit) in current.items():
        if name in base and base[name][0]:
            print(f"{name}: {base[name][0]:g} {value:g} {value / base[name][0]:.2f}x ({unit})")


if __name__ == "__main__":
    main()
