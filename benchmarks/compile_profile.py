"""Where a cold start's compile time goes: MA2C's first 300 AV-steps on density 1 in this process
with an empty compiled-kernel cache (``NUMBA_CACHE_DIR`` a new folder), numba's own compile events
recorded. Prints the wall time, the compile time, the time under numba's LLVM lock, and the
functions by their own compile time (type inference, lowering and their LLVM module, excluding the
functions compiled inside it), with the time including those. One torch thread.

    python benchmarks/compile_profile.py [--top 30]
"""

from __future__ import annotations

import argparse
import atexit
import os
import shutil
import tempfile
import time
from collections import defaultdict

os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp()  # before numba reads its configuration
os.environ.setdefault("OMP_NUM_THREADS", "1")

from numba.core import event

atexit.register(shutil.rmtree, os.environ["NUMBA_CACHE_DIR"], ignore_errors=True)


def durations(listener: event.RecordingListener, name_of) -> tuple[dict, dict, dict]:
    """(own, including nested, count) seconds per name of a listener's nested start/end events."""
    stack: list[list] = []
    own: dict[str, float] = defaultdict(float)
    total: dict[str, float] = defaultdict(float)
    count: dict[str, int] = defaultdict(int)
    for stamp, ev in listener.buffer:
        if ev.is_start:
            stack.append([name_of(ev), stamp, 0.0])
            continue
        name, start, nested = stack.pop()
        total[name] += stamp - start
        own[name] += stamp - start - nested
        count[name] += 1
        if stack:
            stack[-1][2] += stamp - start
    return own, total, count


def function_name(ev: event.Event) -> str:
    """A compile event's function and argument types, shortened."""
    dispatcher = ev.data["dispatcher"]
    name = getattr(getattr(dispatcher, "py_func", None), "__qualname__", str(dispatcher))
    return f"{name}{str(ev.data['args'])[:60]}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--top", type=int, default=30, help="functions listed")
    args = parser.parse_args()
    compiles, llvm = event.RecordingListener(), event.RecordingListener()
    event.register("numba:compile", compiles)
    event.register("numba:llvm_lock", llvm)
    start = time.perf_counter()
    from sb3_marl.envs import ENV_IDS
    from sb3_marl.runs.hyperparams import load_hyperparams
    from sb3_marl.runs.training import make_model, make_venv

    hyperparams = load_hyperparams("ma2c", ENV_IDS[1])
    model = make_model("ma2c", make_venv(ENV_IDS[1], hyperparams, seed=0), hyperparams, seed=0)
    model.learn(300)
    wall = time.perf_counter() - start
    own, total, count = durations(compiles, function_name)
    llvm_own = durations(llvm, lambda ev: "llvm")[0]["llvm"]
    print(f"wall_time: {wall:.1f} s")
    print(f"compile_time: {sum(own.values()):.1f} s")
    print(f"llvm_lock_time: {llvm_own:.1f} s")
    print(f"compiled_functions: {len(own)} count")
    print(f"# own [s], with nested [s], compiles, function (the top {args.top})")
    for name in sorted(own, key=own.__getitem__, reverse=True)[: args.top]:
        print(f"# {own[name]:6.2f} {total[name]:6.2f} {count[name]} {name}")


if __name__ == "__main__":
    main()
