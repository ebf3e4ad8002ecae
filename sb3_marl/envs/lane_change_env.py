"""The multi-agent lane-change scenario of Zhou, Chen et al. on highway-env."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.action import DiscreteMetaAction
from highway_env.envs.common.graphics import EnvViewer
from highway_env.vehicle.controller import MDPVehicle

from sb3_marl.envs import config as cfg
from sb3_marl.envs.observation import observation_space, observe
from sb3_marl.envs.reward import neighbour_matrix, reward_terms, total_reward
from sb3_marl.envs.road import make_road, spawn_vehicles
from sb3_marl.envs.simulator import COMPILED, CompiledRoad, Simulator
from sb3_marl.envs.supervisor import supervise
from sb3_marl.envs.traffic import TrafficSnapshot

#: Meta-action index -> label, highway-env's ``DiscreteMetaAction`` numbering.
ACTIONS: dict[int, str] = dict(DiscreteMetaAction.ACTIONS_ALL)
ACTION_INDEX: dict[str, int] = {label: index for index, label in ACTIONS.items()}


class LaneChangeEnv(AbstractEnv):
    """One-way highway where ``n_avs`` AVs share the road with IDM/MOBIL human drivers.

    - ``reset`` spawns ``n_avs`` AVs and a number of HDVs sampled from the density's range in
      random grid slots (see :func:`~sb3_marl.envs.road.spawn_vehicles`) and returns
      observations of shape ``(n_avs, obs_vehicles_count, 5)``.
    - ``step(actions)`` takes an int array ``(n_avs,)`` of meta-actions
      (0 LANE_LEFT, 1 IDLE, 2 LANE_RIGHT, 3 FASTER, 4 SLOWER), simulates
      ``simulation_frequency / policy_frequency`` frames of 1 / simulation_frequency s and returns
      the observations, the mean AV reward (the global reward, a scalar for gymnasium),
      ``terminated``, ``truncated`` and an info dict of per-AV arrays (see :meth:`_info`).
    - With ``safety_supervisor``, the proposed actions pass the priority-based safety supervisor
      (:mod:`sb3_marl.envs.supervisor`) first, which replaces those predicted to collide.
    - The episode terminates for all AVs as soon as any AV crashes. It is truncated after
      ``duration * policy_frequency`` steps (100 by default).

    Road end: the simulated lanes are ``road_length`` m long. A vehicle whose centre passes the
    end has left the scenario: it can no longer collide, and it is dropped from every
    observation, headway and neighbour set. HDVs that leave are removed. An AV that leaves keeps
    driving, on the straight continuation of its lane and still under its policy, so its slot
    goes on producing real transitions (its observation then shows no other vehicle ahead); the
    episode is truncated early once every AV has left, since nothing remains to decide.
    """

    viewer: EnvViewer | None  # highway-env's renderer (AbstractEnv sets it)

    metadata = {"render_modes": ["human", "rgb_array"]}
    #: Classes the scenario is built from (compiled frames); ``simulator.STOCK`` (highway-env's own) and
    #: ``simulator.FAST`` give the same episodes, within rounding (tests/envs/test_kernel.py), slower.
    simulator: Simulator = COMPILED

    def __init__(
        self,
        config: dict[str, Any] | None = None,
        render_mode: str | None = None,
        density: int | None = None,
    ) -> None:
        """
        :param config: overrides merged over :func:`~sb3_marl.envs.config.default_config`
        :param render_mode: None, ``"rgb_array"`` (headless) or ``"human"``
        :param density: the registered id's traffic density; ``config["density"]`` wins if given
        """
        if density is not None:
            config = {"density": density, **(config or {})}
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"Invalid render_mode={render_mode!r}: expected one of {self.metadata['render_modes']} or None.")
        self.avs: list[MDPVehicle] = []
        self.n_hdvs = 0
        super().__init__(config=config, render_mode=render_mode)

    @classmethod
    def default_config(cls) -> dict[str, Any]:
        return cfg.default_config()

    def configure(self, config: dict[str, Any] | None) -> None:
        """Merge ``config`` over the current config after validating the result."""
        merged = {**self.config, **(config or {})}
        cfg.validate_config(merged)
        super().configure(config)

    @property
    def n_avs(self) -> int:
        """Number of AVs controlled by this instance."""
        return cfg.resolved_n_avs(self.config)

    @property
    def max_steps(self) -> int:
        """Policy steps in a full episode."""
        return int(round(self.config["duration"] * self.config["policy_frequency"]))

    def define_spaces(self) -> None:
        """Spaces of the current config; rebuilt only when their shapes change (every reset calls this)."""
        shape = (self.n_avs, self.config["obs_vehicles_count"])
        if getattr(self, "_space_shape", None) != shape:
            self.observation_space = observation_space(self.n_avs, self.config)
            self.action_space = spaces.MultiDiscrete(np.full(self.n_avs, len(ACTIONS)))
            self._space_shape = shape

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Spawn a new episode; ``options={"config": {...}}`` reconfigures first, as in highway-env."""
        gym.Env.reset(self, seed=seed)
        if options and "config" in options:
            self.configure(options["config"])
        self.update_metadata()
        self.define_spaces()
        self.time = self.steps = 0
        self.done = False
        self._reset()
        snapshot = self._snapshot()
        obs = observe(snapshot, self.config, self._target_speeds())
        n = self.n_avs
        zeros, none = np.zeros(n), np.full(n, -1, dtype=np.int64)
        info = self._info(snapshot, zeros, np.zeros(n, dtype=bool), np.zeros(n, dtype=bool), none, none)
        if self.render_mode == "human":
            self.render()
        return obs, info

    def _reset(self) -> None:
        self.road = make_road(self.config, self.np_random, self.simulator)
        lo, hi = cfg.resolved_hdv_range(self.config)
        self.n_hdvs = int(self.np_random.integers(lo, hi + 1))
        self.avs, _ = spawn_vehicles(self.road, self.config, self.n_avs, self.n_hdvs, self.np_random, self.simulator)
        self.controlled_vehicles = list(self.avs)
        self._exited = np.zeros(self.n_avs, dtype=bool)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Apply one meta-action per AV for 1 / policy_frequency s of simulation."""
        if self.road is None:
            raise RuntimeError("Call reset() before step().")
        if self.done:
            raise RuntimeError("The episode is over (terminated or truncated): call reset() before step().")
        proposed = self._check_actions(action)
        actions = proposed
        # the road's state, captured once per step: the supervisor predicts from it, the compiled road moves it
        state = self.road.capture() if self._compiled() else None
        if self.config["safety_supervisor"]:
            actions, _ = supervise(self.road.vehicles, self.n_avs, proposed, self.action_masks(), self.config, state)
        speed_before = np.array([av.speed for av in self.avs])
        lanes_before = [av.target_lane_index for av in self.avs]

        self._simulate(actions, state)
        self.time += 1.0 / self.config["policy_frequency"]

        snapshot = self._snapshot()
        acceleration = (snapshot.speed[: self.n_avs] - speed_before) * self.config["policy_frequency"]
        lane_change = np.array([av.target_lane_index != before for av, before in zip(self.avs, lanes_before)])
        crashed = np.array([av.crashed for av in self.avs])
        info = self._info(snapshot, acceleration, lane_change, crashed, proposed, actions)

        terminated = bool(crashed.any())
        truncated = not terminated and (self.steps_done >= self.max_steps or bool(self._exited.all()))
        self.done = terminated or truncated
        if self.render_mode == "human":
            self.render()
        return (
            observe(snapshot, self.config, self._target_speeds()),
            float(info["rewards"].mean()),
            terminated,
            truncated,
            info,
        )

    def _compiled(self) -> bool:
        """Whether this step runs in compiled code: a :class:`~sb3_marl.envs.simulator.CompiledRoad`
        of the scenario's geometry, and nothing to draw between frames (no viewer, no history)."""
        road = self.road
        return (
            isinstance(road, CompiledRoad)
            and self.viewer is None
            and not road.record_history
            and bool(road.compiled_geometry())
        )

    def _simulate(self, actions: np.ndarray, state: np.ndarray | None = None) -> None:
        """Apply the executed meta-actions and simulate the frames of one policy step (``state``:
        the road's state captured this step, for the compiled road).

        With a :class:`~sb3_marl.envs.simulator.CompiledRoad` and nothing to draw between frames
        (no viewer, no trajectory history) the frames run in compiled code; otherwise frame by
        frame with highway-env's ``Road.act`` / ``Road.step``, rendering the frames in between.
        """
        frames = self.config["simulation_frequency"] // self.config["policy_frequency"]
        dt = 1.0 / self.config["simulation_frequency"]
        road = self.road
        if self._compiled():
            for av, a in zip(self.avs, actions):
                av.decide(ACTIONS[int(a)])
            road.simulate(frames, dt, exit_x=self.config["road_length"], state=state)
            self.steps += frames
            self._remove_exited()
            return
        for frame in range(frames):
            if frame == 0:
                for av, a in zip(self.avs, actions):
                    av.act(ACTIONS[int(a)])
            road.act()
            road.step(dt)
            self.steps += 1
            self._remove_exited()
            if frame < frames - 1:
                self._automatic_rendering()
        self.enable_auto_render = False

    def render(self) -> np.ndarray | None:
        """Render with highway-env's viewer; ``rgb_array`` frames are drawn offscreen, headless.

        highway-env disables drawing when ``SDL_VIDEODRIVER=dummy`` (the usual headless setting),
        which would give black frames; offscreen surfaces need no display, so drawing stays on.
        """
        if self.viewer is None and self.render_mode == "rgb_array":
            self.viewer = EnvViewer(self)
            self.viewer.enabled = True
        return super().render()

    @property
    def steps_done(self) -> int:
        """Policy steps taken in the current episode."""
        return self.steps // (self.config["simulation_frequency"] // self.config["policy_frequency"])

    def action_masks(self) -> np.ndarray:
        """(n_avs, 5) bool: which meta-actions are available to each AV.

        Same rule as highway-env's ``DiscreteMetaAction.get_available_actions``: IDLE always;
        a lane change only towards an existing lane reachable from the AV's position; FASTER /
        SLOWER unless the AV already tracks the highest / lowest target speed.
        """
        rows = []
        graph = self.road.network.graph
        for av in self.avs:
            _from, _to, lane_id = av.lane_index
            lanes = graph[_from][_to]  # RoadNetwork.side_lanes: the neighbouring ids of this segment
            left, right = (
                0 <= side < len(lanes) and lanes[side].is_reachable_from(av.position) for side in (lane_id - 1, lane_id + 1)
            )
            rows.append((left, True, right, av.speed_index < av.target_speeds.size - 1, av.speed_index > 0))
        return np.array(rows, dtype=bool).reshape(self.n_avs, len(ACTIONS))

    def _check_actions(self, action: Any) -> np.ndarray:
        actions = np.asarray(action)
        if actions.shape == () and self.n_avs == 1:
            actions = actions.reshape(1)
        if actions.shape != (self.n_avs,) or not np.issubdtype(actions.dtype, np.integer):
            raise ValueError(
                f"Invalid action {action!r}: expected an int array of shape ({self.n_avs},), "
                f"one meta-action per AV, got dtype {actions.dtype} and shape {actions.shape}."
            )
        if ((actions < 0) | (actions >= len(ACTIONS))).any():
            raise ValueError(f"Invalid action {actions.tolist()}: each must be in {ACTIONS}.")
        return actions

    def _remove_exited(self) -> None:
        """Take vehicles past the road end out of the scenario (see the class docstring)."""
        road_length = self.config["road_length"]
        for i, av in enumerate(self.avs):
            if not self._exited[i] and av.position[0] > road_length:
                self._exited[i] = True
                av.collidable = False
        self.road.vehicles = [v for v in self.road.vehicles if v.position[0] <= road_length or v in self.controlled_vehicles]

    def _snapshot(self) -> TrafficSnapshot:
        return TrafficSnapshot.capture(self.road.vehicles, self.n_avs, self.config["road_length"])

    def _target_speeds(self) -> np.ndarray | None:
        """[m/s] the AVs' target speeds, for the ``obs_target_speed`` feature (None without it)."""
        return np.array([av.target_speed for av in self.avs]) if self.config["obs_target_speed"] else None

    def _info(
        self,
        snapshot: TrafficSnapshot,
        acceleration: np.ndarray,
        lane_change: np.ndarray,
        crashed: np.ndarray,
        proposed: np.ndarray,
        executed: np.ndarray,
    ) -> dict[str, Any]:
        """Per-AV arrays of shape (n_avs,) unless stated.

        ``rewards`` (the weighted total), ``reward_terms`` (dict of unweighted terms, see
        :mod:`sb3_marl.envs.reward`), ``neighbours`` ((n_avs, n_avs) bool, the local reward's
        sets), ``crashed``, ``speed`` [m/s], ``headway`` [m], ``acceleration`` [m/s²],
        ``lane_change``, ``exited`` (past the road end), ``action_mask`` ((n_avs, 5) bool, for
        the next step), ``proposed_action`` (the policy's), ``executed_action`` (after the safety
        supervisor; both -1 after a reset), ``intervened`` (the supervisor replaced the action),
        and the scalars ``n_avs``, ``n_hdvs``, ``step``.
        """
        terms = reward_terms(snapshot, crashed, acceleration, lane_change, self.config)
        headway = terms.pop("headway_distance")
        return {
            "rewards": total_reward(terms, self.config),
            "reward_terms": terms,
            "neighbours": neighbour_matrix(snapshot),
            "crashed": crashed,
            "speed": snapshot.speed[: self.n_avs].copy(),
            "headway": headway,
            "acceleration": acceleration,
            "lane_change": lane_change,
            "exited": self._exited.copy(),
            "action_mask": self.action_masks(),
            "proposed_action": np.asarray(proposed, dtype=np.int64),
            "executed_action": np.asarray(executed, dtype=np.int64),
            "intervened": np.asarray(proposed) != np.asarray(executed),
            "n_avs": self.n_avs,
            "n_hdvs": self.n_hdvs,
            "step": self.steps_done,
        }
