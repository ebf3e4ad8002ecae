"""A fresh install's first command: ``sb3-marl train --algo ma2c -n 300`` in a new process with an
empty compiled-kernel cache (``NUMBA_CACHE_DIR`` a new folder: a fresh install, a new cluster node,
any change of the compiled sources), then the same command again with that cache filled, and
``sb3-marl --help`` beside rl_zoo3's ``train --help``. One torch thread, wall time of the whole
process (imports included). Prints ``name: value unit`` lines and the train command's own report.

    python benchmarks/first_run.py [--rounds 1]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent


def timed(argv: list[str], env: dict[str, str], cwd: str) -> tuple[float, str]:
    """(wall time [s], output) of ``argv`` in a new process."""
    start = time.perf_counter()
    done = subprocess.run(argv, env=env, cwd=cwd, capture_output=True, text=True, check=True)
    return time.perf_counter() - start, done.stdout + done.stderr


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=1, help="cold/warm pairs, each with a new empty cache")
    args = parser.parse_args()
    train = [str(BIN / "sb3-marl"), "train", "--algo", "ma2c", "-n", "300", "--eval-freq", "-1", "-f", "logs"]
    for round_ in range(args.rounds):
        with tempfile.TemporaryDirectory() as folder:
            env = {**os.environ, "OMP_NUM_THREADS": "1", "NUMBA_CACHE_DIR": str(Path(folder) / "numba")}
            cold, out = timed(train, env, folder)
            warm, _ = timed(train, env, folder)
            entries = sum(1 for _ in (Path(folder) / "numba").rglob("*.nbi"))
            size = sum(p.stat().st_size for p in (Path(folder) / "numba").rglob("*") if p.is_file())
        report = [line for line in out.splitlines() if "compil" in line or "wall time" in line]
        print(f"# round {round_ + 1}: {' | '.join(report)}")
        print(f"first_train_empty_cache: {cold:.1f} s")
        print(f"second_train_warm_cache: {warm:.1f} s")
        print(f"compiled_entries: {entries}")
        print(f"cache_size: {size / 1e6:.1f} MB")
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory() as folder:
        ours, _ = timed([str(BIN / "sb3-marl"), "--help"], env, folder)
        zoo, _ = timed([sys.executable, "-m", "rl_zoo3.train", "--help"], env, folder)
    print(f"sb3_marl_help: {ours:.1f} s")
    print(f"rl_zoo3_train_help: {zoo:.1f} s")


if __name__ == "__main__":
    main()
