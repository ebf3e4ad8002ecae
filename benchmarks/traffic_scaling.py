"""Time per vehicle-step of one scenario env against the number of vehicles on a longer road.

The lane change's highway with ``--lanes`` lanes, long enough for every vehicle on the spawn grid
(40 m slots, one vehicle per slot), from 12 to 800 vehicles, 6 of them AVs (the largest count of
density 3: the config's ``n_avs`` stays within the density's range), the rest HDVs: one env
steps seeded random available meta-actions for ``--steps`` policy steps (resets included), with
the safety supervisor off and on. Prints ``name: value unit`` lines (µs per vehicle-step and
env-steps/s per count) and writes the plot ``--plot`` (log-log) if given. Linear cost would keep
the time per vehicle-step flat; all-pairs neighbour searches make it grow with the count.

    python benchmarks/traffic_scaling.py [--counts 12 50 200 800] [--steps 200] [--plot results/speed/traffic_scaling.png]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from sb3_marl.envs import ENV_IDS, make_scenario

SPAWN_SPACING = 40.0  # [m] between spawn slots of a lane (the scenario's default)
AVS = 6  # the AVs of every road: density 3's largest count


def scenario_config(vehicles: int, lanes: int, supervisor: bool) -> dict:
    """A highway of ``lanes`` lanes with one spawn slot per vehicle (plus a spare per lane),
    :data:`AVS` AVs and HDVs for the rest; the road extends 200 m past the last slot."""
    slots = -(-vehicles // lanes) + 1
    n_avs = AVS
    return {
        "n_avs": n_avs,
        "hdv_count_range": [vehicles - n_avs, vehicles - n_avs],
        "lanes_count": lanes,
        "spawn_slots_per_lane": slots,
        "road_length": 10.0 + slots * SPAWN_SPACING + 200.0,
        "safety_supervisor": supervisor,
    }


def seconds_per_step(vehicles: int, lanes: int, supervisor: bool, steps: int) -> float:
    env = make_scenario(ENV_IDS[3], scenario_config(vehicles, lanes, supervisor))
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    env.step(np.ones(env.n_avs, dtype=np.int64))  # warm-up: compiled code
    env.reset(seed=1)
    start = time.perf_counter()
    for _ in range(steps):
        masks = env.action_masks()
        _, _, terminated, truncated, _ = env.step(np.where(masks, rng.random(masks.shape), -1.0).argmax(axis=1))
        if terminated or truncated:
            env.reset()
    env.close()
    return (time.perf_counter() - start) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", type=int, nargs="+", default=[12, 50, 200, 800])
    parser.add_argument("--lanes", type=int, default=4)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--plot", default=None, help="write a log-log plot of µs per vehicle-step here")
    args = parser.parse_args()
    per_vehicle: dict[bool, list[float]] = {False: [], True: []}
    for vehicles in args.counts:
        for supervisor in (False, True):
            step = seconds_per_step(vehicles, args.lanes, supervisor, args.steps)
            per_vehicle[supervisor].append(step / vehicles * 1e6)
            tag = f"vehicles{vehicles}_supervisor_{'on' if supervisor else 'off'}"
            print(f"{tag}: {step * 1e6 / vehicles:.2f} us/vehicle-step", flush=True)
            print(f"{tag}_env_steps: {1 / step:.0f} env-steps/s", flush=True)
    for supervisor, values in per_vehicle.items():
        print(
            f"growth_{args.counts[0]}_to_{args.counts[-1]}_supervisor_{'on' if supervisor else 'off'}: "
            f"{values[-1] / values[0]:.2f} x per vehicle-step"
        )
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from sb3_marl.common.files import save_figure

        figure, axis = plt.subplots(figsize=(5, 3.5))
        for supervisor, values in per_vehicle.items():
            axis.plot(args.counts, values, marker="o", label=f"supervisor {'on' if supervisor else 'off'}")
        axis.set(xscale="log", yscale="log", xlabel="vehicles on the road", ylabel="µs per vehicle-step")
        axis.set_title(f"One env step, {args.lanes}-lane highway, {AVS} AVs")
        axis.legend()
        figure.tight_layout()
        save_figure(figure, args.plot)
        print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
