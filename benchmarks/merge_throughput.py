"""Env-steps/s of the merge scenario vs stock highway-env classes on the same merging road.

The reference is MARL_CAVs' ``merge_env_v1`` rebuilt on highway-env 1.12 (theirs needs Python 3.6
and gym 0.x): highway-env's ``AbstractEnv`` with its multi-agent ``Kinematics`` observation and
``DiscreteMetaAction``, the same road, obstacle and spawn, their reward and regional reward
computed on highway-env's objects each step. Both take uniformly random meta-actions for every AV
(seeded) at each density's maximum counts, resetting when an episode ends (resets included), on
one process, ours after 20 untimed steps that load its compiled code. The two alternate over
``--rounds`` rounds (the machine's speed drifts between them), each timing ``--steps / --rounds``
stock steps and ten times as many of ours (at the stock's count ours would be timed over a fraction
of a second, within the machine's noise); each line is the median over the rounds, the speedup's
the median of the rounds' own ratios. Prints ``name: value unit`` lines.

    python benchmarks/merge_throughput.py [--steps 2000] [--rounds 5] [--densities 1 2 3]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym
import numpy as np
from highway_env import utils
from highway_env.envs.common.abstract import AbstractEnv

import sb3_marl  # noqa: F401  (registers our ids)
from sb3_marl.envs import MERGE_ENV_IDS
from sb3_marl.envs.config import MERGE_DENSITIES, merge_default_config
from sb3_marl.sim.merge_road import ENDS, make_merge_road
from sb3_marl.sim.simulator import vehicle_objects
from sb3_marl.sim.spawn import draw_episode, spawn_parameters

sys.path.insert(0, str(Path(__file__).resolve().parent))
from env_throughput import steps_per_second


class StockMergeEnv(AbstractEnv):
    """MARL_CAVs' ``MergeEnvMARL`` on highway-env 1.12's classes (the benchmark's reference)."""

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        config.update(
            {
                "observation": {"type": "MultiAgentObservation", "observation_config": {"type": "Kinematics"}},
                "action": {"type": "MultiAgentAction", "action_config": {"type": "DiscreteMetaAction"}},
                "simulation_frequency": 15,
                "policy_frequency": 5,
                "duration": 20,
                "n_avs": 3,
                "n_hdvs": 3,
            }
        )
        return config

    def _reset(self) -> None:
        self.road = make_merge_road({**merge_default_config(), "show_trajectories": False}, self.np_random)
        n_hdvs = self.config["n_hdvs"]
        spawn = spawn_parameters(merge_default_config(), (n_hdvs, n_hdvs), merge=True)
        _, state = draw_episode(self.np_random, self.config["n_avs"], spawn)
        self.road.vehicles = vehicle_objects(self.road, state, merge_default_config())
        self.controlled_vehicles = self.road.vehicles[: self.config["n_avs"]]

    def _agent_reward(self, vehicle) -> float:
        scaled_speed = utils.lmap(vehicle.speed, [10, 30], [0, 1])
        merging = 0.0
        if vehicle.lane_index == ("b", "c", 1):
            merging = -np.exp(-((vehicle.position[0] - sum(ENDS[:3])) ** 2) / (10 * ENDS[2]))
        headway = 60.0
        for v in self.road.vehicles:
            if v.lane_index == vehicle.lane_index and v.position[0] > vehicle.position[0]:
                headway = min(headway, v.position[0] - vehicle.position[0])
        headway_cost = np.log(headway / (1.2 * vehicle.speed)) if vehicle.speed > 0 else 0
        return -200 * vehicle.crashed + np.clip(scaled_speed, 0, 1) + 4 * merging + 4 * min(headway_cost, 0)

    def _reward(self, action) -> float:
        local = {v: self._agent_reward(v) for v in self.controlled_vehicles}
        for vehicle in self.controlled_vehicles:  # the regional reward's neighbour search
            for lane in (vehicle.lane_index, *self.road.network.side_lanes(vehicle.lane_index)):
                self.road.neighbour_vehicles(vehicle, lane)
        return float(np.mean(list(local.values())))

    def _is_terminated(self) -> bool:
        return any(v.crashed for v in self.controlled_vehicles)

    def _is_truncated(self) -> bool:
        return self.time >= self.config["duration"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="stock env steps per density, over all rounds")
    parser.add_argument("--rounds", type=int, default=5, help="alternating measurements of the two envs")
    parser.add_argument("--densities", type=int, nargs="+", default=sorted(MERGE_DENSITIES))
    args = parser.parse_args()
    for density in args.densities:
        n_avs, n_hdvs = MERGE_DENSITIES[density]["avs"][1], MERGE_DENSITIES[density]["hdvs"][1]
        ours = gym.make(MERGE_ENV_IDS[density], config={"n_avs": n_avs, "hdv_count_range": [n_hdvs, n_hdvs]})
        stock = StockMergeEnv(config={"n_avs": n_avs, "n_hdvs": n_hdvs})
        steps_per_second(ours, 20)  # untimed: loads the compiled code from its cache
        steps = args.steps // args.rounds
        rounds = np.array(
            [
                steps_per_second(ours, 10 * steps, seed=1000 * r) + steps_per_second(stock, steps, seed=1000 * r)
                for r in range(args.rounds)
            ]
        )  # per round: ours (resets included, step only), stock (the same)
        speedup, step_only = rounds[:, 0] / rounds[:, 2], rounds[:, 1] / rounds[:, 3]
        tag = f"merge_density{density}_{n_avs}av_{n_hdvs}hdv"
        print(f"{tag}_ours_env_steps: {np.median(rounds[:, 0]):.1f} steps/s")
        print(f"{tag}_stock_env_steps: {np.median(rounds[:, 2]):.1f} steps/s")
        print(f"{tag}_speedup: {np.median(speedup):.2f} x (rounds {speedup.min():.0f}-{speedup.max():.0f} x)")
        print(f"{tag}_step_only_speedup: {np.median(step_only):.2f} x")


if __name__ == "__main__":
    main()
