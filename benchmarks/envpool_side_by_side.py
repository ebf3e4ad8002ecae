"""Env-steps/s of our batched copies beside EnvPool's C++ port of highway-env, in one run.

EnvPool's ``Highway-v0`` (sail-sg/envpool: single-agent, no safety supervisor) is configured as our
lane-change road is driven: 2 lanes, 12 vehicles (the ego and 11 others), 15 Hz simulation, 5 Hz
policy, a batch of ``--copies`` envs stepped on one thread. Ours: the parameter-sharing VecEnv of
``--copies`` scenario copies at ``--density`` (every AV a slot), in-process, with the safety
supervisor off and on, the copies stepped in one compiled call (the default, ``RoadBatch``) and one by
one (``batched=False``, ``_one_by_one``), and the compiled step of the batch alone
(``_compiled_step_only``: :func:`~sb3_marl.envs.batch_kernel.step_copies` timed on the inputs that
a round of VecEnv steps recorded, without the VecEnv's Python: rewards, slot infos, resets). Both
take seeded uniformly random actions (ours: among each AV's available
meta-actions, drawn in one vectorised call) and auto-reset. Each is measured in turn for
``--rounds`` rounds and the median of each is printed (single timings on a shared 2-core VM drift
by a third), as ``name: value unit`` lines: env-steps/s (one road advanced by one policy step) and
AV-steps/s (our slots; EnvPool controls one vehicle per road). Roads differ: EnvPool's highway is
highway-env's (open-ended, its traffic density), ours is the paper's 520 m road.

EnvPool is optional and not a dependency of sb3-marl: without it, only our numbers are printed.
Its package imports every port's registration at import (Atari ROMs, MuJoCo assets); the script
imports only the highway port's, so ``pip install envpool`` alone (no asset packages) suffices.

    python benchmarks/envpool_side_by_side.py [--density 3] [--copies 16] [--steps 300] [--rounds 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
import types
from collections.abc import Callable
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from sb3_marl.envs import ENV_IDS
from sb3_marl.envs.batch_kernel import CopyState, step_copies
from wrappers import ParameterSharingVecEnv


def load_envpool() -> Any:
    """The envpool module with only its highway port registered; None if it is not installed."""
    sys.modules.setdefault("envpool.entry", types.ModuleType("envpool.entry"))
    try:
        import envpool
        import envpool.highway.registration  # registers Highway-v0
    except ImportError:
        return None
    return envpool


def envpool_round(env: Any, steps: int, rng: np.random.Generator) -> float:
    """Env-steps/s of ``steps`` batched steps of EnvPool's ``env`` with random actions."""
    start = time.perf_counter()
    for _ in range(steps):
        env.step(rng.integers(0, 5, env.config["num_envs"]))
    return steps * env.config["num_envs"] / (time.perf_counter() - start)


def ours_round(venv: ParameterSharingVecEnv, steps: int, rng: np.random.Generator) -> float:
    """Env-steps/s of ``steps`` VecEnv steps (every copy advances one policy step) with random
    available meta-actions: the argmax of uniform scores over each slot's mask."""
    start = time.perf_counter()
    for _ in range(steps):
        masks = venv.action_masks()
        venv.step(np.where(masks, rng.random(masks.shape), -1.0).argmax(axis=1))
    return steps * len(venv.slices) / (time.perf_counter() - start)


def compiled_round(venv: ParameterSharingVecEnv, steps: int, rng: np.random.Generator) -> float:
    """Env-steps/s of the batch's compiled step alone, on the states and actions of ``steps`` VecEnv
    steps (as :func:`ours_round`'s) recorded first."""
    batch, inputs = venv.batch, []
    assert batch is not None, "the compiled step of a batched VecEnv"
    for _ in range(steps):
        masks = venv.action_masks()
        actions = np.where(masks, rng.random(masks.shape), -1.0).argmax(axis=1)
        inputs.append((batch.roads.states, batch.roads.offsets.copy(), actions, CopyState(*(a.copy() for a in batch.copies))))
        venv.step(actions)  # batch.roads.states is a new array after every step and reset
    start = time.perf_counter()
    for states, offsets, actions, copies in inputs:
        step_copies(states, offsets, batch.roads.slot_starts, actions, copies, batch.parameters, respawn=True)
    return steps * len(venv.slices) / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--density", type=int, default=3, choices=sorted(ENV_IDS))
    parser.add_argument("--copies", type=int, default=16)
    parser.add_argument("--steps", type=int, default=300, help="VecEnv steps per round")
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    runs: dict[str, tuple[Callable[[], float], float]] = {}
    for supervisor in (False, True):
        for batched in (True, False):
            venv = ParameterSharingVecEnv(
                ENV_IDS[args.density], n_copies=args.copies, seed=0, config={"safety_supervisor": supervisor}, batched=batched
            )
            venv.reset()
            name = f"ours_density{args.density}_{args.copies}copies_supervisor_{'on' if supervisor else 'off'}"
            name += "" if batched else "_one_by_one"
            runs[name] = (lambda venv=venv: ours_round(venv, args.steps, rng), venv.num_envs / args.copies)
            if batched:
                runs[name + "_compiled_step_only"] = (
                    lambda venv=venv: compiled_round(venv, args.steps, rng),
                    venv.num_envs / args.copies,
                )
    envpool = load_envpool()
    if envpool is None:
        print("envpool: not installed (pip install envpool==1.2.5); EnvPool's numbers are left out")
    else:
        env = envpool.make(
            "Highway-v0",
            env_type="gymnasium",
            num_envs=args.copies,
            batch_size=args.copies,
            num_threads=1,
            seed=0,
            lanes_count=2,
            vehicles_count=11,
            simulation_frequency=15,
            policy_frequency=5,
        )
        env.reset()
        runs[f"envpool_{envpool.__version__}_highway_{args.copies}envs_1thread"] = (
            lambda: envpool_round(env, args.steps, rng),
            1.0,
        )
    for fn, _ in runs.values():  # warm-up: compiled code, first resets
        fn()
    rates: dict[str, list[float]] = {name: [] for name in runs}
    for _ in range(args.rounds):
        for name, (fn, _) in runs.items():
            rates[name].append(fn())
    medians = {name: statistics.median(values) for name, values in rates.items()}
    for name, (_, avs_per_road) in runs.items():
        print(f"{name}: {medians[name]:.0f} env-steps/s")
        print(f"{name}_av_steps: {medians[name] * avs_per_road:.0f} AV-steps/s")
    for name in medians:
        if name.endswith("_one_by_one") or name.endswith("_compiled_step_only"):
            batched = name.removesuffix("_one_by_one").removesuffix("_compiled_step_only")
            other = name.removeprefix(batched + "_")
            print(f"{batched}_batched_vs_{other}: {medians[batched] / medians[name]:.2f} x")
    for name in medians:  # what a supervised step costs against an unsupervised one (issue 70: at most 2x)
        if "_supervisor_on" in name:
            off = name.replace("_supervisor_on", "_supervisor_off")
            print(f"{name}_step_cost_vs_off: {medians[off] / medians[name]:.2f} x")
    peer = next((medians[name] for name in medians if name.startswith("envpool")), None)
    if peer is not None:
        for name in medians:
            if name.startswith("ours"):
                print(f"{name}_vs_envpool: {medians[name] / peer:.3f} x")
    print(f"rounds: {args.rounds} (median of each); steps per round: {args.steps}")


if __name__ == "__main__":
    main()
