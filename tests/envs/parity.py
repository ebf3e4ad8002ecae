"""Seeded episodes of the scenario under two simulators, side by side (parity checks of the kernel).

The env's default, :data:`~sb3_marl.sim.simulator.COMPILED` (the kernel on the state array),
agrees with :data:`~sb3_marl.sim.simulator.STOCK` (highway-env's own classes stepping frame by
frame) within a rounding tolerance (see :mod:`sb3_marl.sim.kernel`). :func:`compare` runs the
same seeded episodes, with the same actions, under two simulators and reports the largest state
difference and every episode whose outcome differs. Used by tests/envs/test_kernel.py and
benchmarks/kernel_parity.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sb3_marl.envs import make_scenario
from sb3_marl.sim.kernel import ACCELERATION, CRASHED, HEADING, LANE, SPEED, STEERING, TARGET_LANE, VEHICLE_ID, X, Y

#: Meta-action probabilities (LANE_LEFT, IDLE, LANE_RIGHT, FASTER, SLOWER). Uniform random actions
#: end most episodes in a crash within a few steps; "cruise" is mostly IDLE, so that episodes last
#: and HDVs overtake by MOBIL, with some lane and speed changes of the AVs.
ACTION_PROBABILITIES = {"uniform": [0.2] * 5, "cruise": [0.04, 0.8, 0.04, 0.06, 0.06]}


#: The state columns compared: position [m], heading [rad], speed [m/s], lane, target lane,
#: crashed, steering [rad] and acceleration [m/s²] of the low-level action.
COMPARED = [X, Y, HEADING, SPEED, LANE, TARGET_LANE, CRASHED, STEERING, ACCELERATION]
STANDSTILL = 0.5  # [m/s] below it a vehicle's steering is not compared (see :func:`compare`)


def vehicle_states(env) -> np.ndarray:
    """(vehicles, 9) the :data:`COMPARED` columns of the env's state, road order."""
    return env.state[:, COMPARED].copy()


@dataclass
class Episode:
    """One seeded episode: per step the vehicle states and observation, and its outcome."""

    states: list[np.ndarray] = field(default_factory=list)
    ids: list[np.ndarray] = field(default_factory=list)  # per step: the vehicles' ids, road order
    observations: list[np.ndarray] = field(default_factory=list)
    #: per step: terminated, truncated, the AVs' crash and lane-change flags, the HDVs' target lanes
    events: list[tuple] = field(default_factory=list)

    @property
    def outcome(self) -> tuple[int, bool, int]:
        """(length in policy steps, crashed, lane changes of the AVs)."""
        return len(self.events), bool(self.events[-1][0]), sum(sum(e[3]) for e in self.events)


def run_episode(simulator: str, env_id: str, seed: int, policy: str, **config) -> Episode:
    """An episode of the scenario ``env_id`` from ``reset(seed=seed)`` under ``simulator``, the AVs'
    actions drawn from :data:`ACTION_PROBABILITIES` ``[policy]`` by a generator seeded with ``seed``."""
    env = make_scenario(env_id, config)
    env.simulator = simulator
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    episode = Episode(states=[vehicle_states(env)], ids=[env.state[:, VEHICLE_ID].copy()], observations=[obs])
    while True:
        obs, _, terminated, truncated, info = env.step(rng.choice(5, env.n_avs, p=ACTION_PROBABILITIES[policy]))
        hdv_targets = tuple(env.state[env.n_avs :, TARGET_LANE].astype(int).tolist())
        episode.states.append(vehicle_states(env))
        episode.ids.append(env.state[:, VEHICLE_ID].copy())
        episode.observations.append(obs)
        episode.events.append(
            (terminated, truncated, tuple(info["crashed"].tolist()), tuple(info["lane_change"].tolist()), hdv_targets)
        )
        if terminated or truncated:
            return episode


@dataclass
class Comparison:
    """How far two simulators' episodes are apart."""

    episodes: int = 0
    max_state_difference: float = 0.0  # largest |difference| of any vehicle state entry
    max_observation_difference: float = 0.0
    #: largest |difference| of the vehicles that stood still (< STANDSTILL) earlier in the episode
    #: (observations are compared until the first standstill)
    standstill_difference: float = 0.0
    different_outcomes: list[int] = field(default_factory=list)  # seeds whose events differ
    crashes: int = 0
    hdv_lane_changes: int = 0


def compare(reference: str, candidate: str, env_id: str, seeds: range, policy: str, **config) -> Comparison:
    """Run each seed under both simulators (scenario ``config`` overrides) and compare states,
    observations and events."""
    result = Comparison()
    for seed in seeds:
        a = run_episode(reference, env_id, seed, policy, **config)
        b = run_episode(candidate, env_id, seed, policy, **config)
        result.episodes += 1
        result.crashes += a.outcome[1]
        result.hdv_lane_changes += sum(x != y for e, f in zip(a.events, a.events[1:]) for x, y in zip(e[4], f[4]))
        if a.events != b.events or len(a.states) != len(b.states):
            result.different_outcomes.append(seed)
            continue
        stood_still: set[float] = set()  # ids of the vehicles that stood still earlier in the episode
        for s, t, o, p, ids in zip(a.states, b.states, a.observations, b.observations, a.ids):
            if s.shape != t.shape:
                result.different_outcomes.append(seed)
                break
            if not s.size:
                continue
            # the steering command divides by the speed: after a standstill (a vehicle stranded at
            # the merging lane's end, an AV the supervisor braked to a stop) last-bit differences of
            # the heading flip it, so such vehicles are compared apart (tracked by id)
            stood_still.update(ids[np.abs(s[:, COMPARED.index(SPEED)]) < STANDSTILL].tolist())
            stopped = np.isin(ids, list(stood_still))
            difference = np.abs(s - t)
            result.max_state_difference = max(result.max_state_difference, float(difference[~stopped].max(initial=0.0)))
            result.standstill_difference = max(result.standstill_difference, float(difference[stopped].max(initial=0.0)))
            if not stopped.any():  # the AVs observe the stranded vehicles too
                result.max_observation_difference = max(result.max_observation_difference, float(np.abs(o - p).max()))
    return result


def stock_rule_actions(env, acceleration_threshold: float = 1.0) -> np.ndarray:
    """The rule driver with highway-env's own objects (the parity reference of
    :func:`sb3_marl.sim.drivers.rule_actions`): for each AV, an ``IDMVehicle`` with the AV's state
    and the config's MOBIL parameters, aiming at ``speed_limit``, takes the AV's place on the road;
    a lane change MOBIL accepts becomes LANE_LEFT / LANE_RIGHT, else the IDM acceleration gives
    FASTER / SLOWER beyond +- ``acceleration_threshold`` [m/s²], else IDLE."""
    from highway_env.vehicle.behavior import IDMVehicle

    from sb3_marl.envs.lane_change_env import ACTION_INDEX
    from sb3_marl.sim.road import configure_hdv

    road, masks, actions = env.road, env.action_masks(), []
    for av, mask in zip(env.avs, masks):
        driver = IDMVehicle.create_from(av)
        configure_hdv(driver, env.config)
        driver.target_speed = env.config["speed_limit"]
        slot = road.vehicles.index(av)
        road.vehicles[slot] = driver  # neighbour searches see the driver, not the AV
        action = None
        try:
            if av.lane_index == av.target_lane_index and abs(av.speed) >= 1:
                for side in road.network.side_lanes(av.lane_index):
                    candidate = ACTION_INDEX["LANE_LEFT" if side[2] < av.lane_index[2] else "LANE_RIGHT"]
                    if mask[candidate] and driver.mobil(side):
                        action = candidate
                        break
            front, _ = road.neighbour_vehicles(driver, driver.lane_index)
            acceleration = driver.acceleration(driver, front)
        finally:
            road.vehicles[slot] = av
        if action is None:
            action = ACTION_INDEX["IDLE"]
            if acceleration > acceleration_threshold and mask[ACTION_INDEX["FASTER"]]:
                action = ACTION_INDEX["FASTER"]
            elif acceleration < -acceleration_threshold and mask[ACTION_INDEX["SLOWER"]]:
                action = ACTION_INDEX["SLOWER"]
        actions.append(action)
    return np.array(actions)
