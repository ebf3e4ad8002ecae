"""The multi-agent lane-change scenario of Zhou, Chen et al. on highway-env."""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.graphics import EnvViewer
from highway_env.road.road import Road
from highway_env.vehicle.controller import MDPVehicle

from sb3_marl.envs import config as cfg
from sb3_marl.envs.batch_kernel import (
    BatchStep,
    StepParameters,
    observe_copies,
    step_copies,
    step_report,
    supervise_road,
)
from sb3_marl.envs.observation import observation_space
from sb3_marl.envs.roads import Roads
from sb3_marl.envs.scenario_road import ScenarioRoad, highway_env_road, scenario_road
from sb3_marl.safety.supervisor import Supervisor
from sb3_marl.sim import drivers, kernel, lanes, meta_actions, pcg64
from sb3_marl.sim.merge_road import MERGING_LANE
from sb3_marl.sim.meta_actions import ACTION_INDEX, ACTIONS
from sb3_marl.sim.road import vehicle_state
from sb3_marl.sim.simulator import COMPILED, SIMULATORS, STOCK, capture, step_objects, vehicle_objects
from sb3_marl.sim.spawn import new_episode, spawn_parameters

__all__ = ["ACTIONS", "ACTION_INDEX", "LaneChangeEnv"]


class LaneChangeEnv(AbstractEnv):
    """One-way highway where ``n_avs`` AVs share the road with IDM/MOBIL human drivers.

    - ``reset`` spawns ``n_avs`` AVs and a number of HDVs sampled from the density's range in random
      grid slots (:func:`~sb3_marl.sim.spawn.new_episode`); observations are ``(n_avs, obs_vehicles_count, 5)``.
    - ``step(actions)`` takes one meta-action per AV (0 LANE_LEFT, 1 IDLE, 2 LANE_RIGHT, 3 FASTER,
      4 SLOWER), simulates ``simulation_frequency / policy_frequency`` frames of 1 /
      simulation_frequency s and returns the observations, the mean AV reward (a scalar for
      gymnasium), ``terminated``, ``truncated`` and an info dict of per-AV arrays (:meth:`_observe`).
    - With ``safety_supervisor``, the proposed actions pass the priority-based safety supervisor
      (:mod:`sb3_marl.safety.supervisor`) first, which replaces those predicted to collide; with
      ``supervisor_shadow`` and the supervisor off, it only reports where it would have
      (``info["intervened"]``).
    - The episode ends for all AVs when any AV crashes, or after ``duration * policy_frequency`` steps.

    Road end: the simulated lanes are ``road_length`` m long. A vehicle whose centre passes the
    end has left the scenario: it can no longer collide, and it is dropped from every
    observation, headway and neighbour set. HDVs that leave are removed. An AV that leaves keeps
    driving, on the straight continuation of its lane and still under its policy, so its slot
    goes on producing real transitions (its observation then shows no other vehicle ahead); the
    episode is truncated early once every AV has left, since nothing remains to decide.

    State: :attr:`state`, one row per vehicle on the road (:mod:`~sb3_marl.sim.kernel`'s columns,
    the AVs first), stepped by compiled code; it, the episode's clock, HDV count, supervisor draw
    and generator live in a :class:`~sb3_marl.envs.roads.Roads` (this env's own, or a batch's that
    holds several copies). :attr:`road` shows it as highway-env objects, built
    when read; highway-env's own classes step those objects frame by frame instead while frames are
    drawn (a viewer, ``show_trajectories``) or with ``simulator = "stock"`` (the parity reference,
    same episodes within rounding: tests/envs/test_kernel.py).
    """

    viewer: EnvViewer | None  # highway-env's renderer (AbstractEnv sets it)

    metadata = {"render_modes": ["human", "rgb_array"]}
    scenario: str = cfg.LANE_CHANGE  #: the config's scenario (:mod:`~sb3_marl.envs.config`)
    simulator: str = COMPILED  #: ``"compiled"`` (default) or ``"stock"`` (:mod:`~sb3_marl.sim.simulator`)
    _roads: Roads  # where this env's road lives: road _k of it (set by the first configure)
    _k = 0
    _np_random: np.random.Generator | None  # gymnasium's
    _dropout = 0.0  # probability that an episode runs without the configured supervisor
    _dropout_stream: int | None = None
    _road: Road | None = None
    _road_at = -1  # the road store's change count when _road's vehicles were the state
    _scenario_road: ScenarioRoad  # the config's road (set by the first configure)

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
        super().__init__(config=config, render_mode=render_mode)

    @classmethod
    def default_config(cls) -> dict[str, Any]:
        return cfg.scenario_default_config(cls.scenario)

    def configure(self, config: dict[str, Any] | None) -> None:
        """Merge ``config`` over the current config after validating the result."""
        merged = {**self.config, **(config or {})}
        cfg.validate_config(merged, self.scenario)
        self._check_n_avs(cfg.resolved_n_avs(merged, self.scenario))
        super().configure(config)
        self._derive()
        if config and "safety_supervisor" in config:  # from now on (else: the episode's draw stays)
            self._roads.copies.supervise[self._k] = bool(self.config["safety_supervisor"])

    def _derive(self) -> None:
        """What the steps read from the config: the road and time grid, the safety supervisor, the
        compiled step's parameters, the road's store (its supervisor switch is the episode's:
        reset draws it, :meth:`configure` sets it)."""
        n_avs = cfg.resolved_n_avs(self.config, self.scenario)
        self._check_n_avs(n_avs)
        self._scenario_road = road = scenario_road(self.config, self.scenario)
        self.supervisor = Supervisor.from_config(self.config, road.lanes, road.end)
        self.horizon = self.supervisor.horizon
        self._n_avs = n_avs
        self._parameters = self.step_parameters()
        roads: Roads | None = getattr(self, "_roads", None)
        if roads is None:
            self._home(Roads(np.array([n_avs])), 0)
        elif roads.n_avs[self._k] != n_avs:
            self._home(roads.resized(n_avs), 0)
        c, on = self._roads.copies, bool(self.config["safety_supervisor"])
        c.shadow[self._k], c.dropout[self._k] = bool(self.config["supervisor_shadow"]), self._dropout if on else 0.0

    def _check_n_avs(self, n_avs: int) -> None:
        """A RuntimeError, before anything changes, where a batch's copy would change its AV count."""
        roads: Roads | None = getattr(self, "_roads", None)
        if roads is not None and roads.batched and roads.n_avs[self._k] != n_avs:
            raise RuntimeError(
                f"Scenario copy {self._k} of a batch cannot change n_avs ({roads.n_avs[self._k]} -> {n_avs}): "
                "a batch steps copies of one config (use batched=False to step the copies one by one)."
            )

    def _home(self, roads: Roads, k: int) -> None:
        """This env's road becomes road ``k`` of ``roads``."""
        self._roads, self._k, self._road_at = roads, k, -1

    def __deepcopy__(self, memo: dict[int, Any]) -> LaneChangeEnv:
        """highway-env's deep copy (without the viewer) that steps alone: a batch's copy takes its
        road, episode record and generator (lent or not) out of the batch's store into its own."""
        roads = self._roads
        if roads.batched:
            own = Roads.join([(roads, self._k)])
            own._lent = {road: copy.deepcopy(generator, memo) for road, generator in own._lent.items()}
            memo[id(roads)] = own
        result = super().__deepcopy__(memo)
        if roads.batched:
            result._k = 0
        return result

    def set_supervisor_dropout(self, dropout: float, stream: int) -> None:
        """With the supervisor configured on, each episode runs without it with probability
        ``dropout``, drawn at its start from a generator of its own, seeded at a seeded reset as
        ``np.random.default_rng([seed, stream])`` (ParameterSharingVecEnv's ``supervisor_dropout``)."""
        self._dropout, self._dropout_stream = float(dropout), int(stream)
        self._roads.copies.dropout_generators[self._k] = pcg64.read_state(np.random.default_rng())
        self._derive()

    def step_parameters(self) -> StepParameters:
        """What a compiled step of this scenario reads from its current config."""
        c, merge = self.config, self._scenario_road.merge
        return StepParameters(
            self.horizon,
            float(c["policy_frequency"]),
            self.max_steps,
            float(c["headway_time"]),
            float(c["supervisor_min_gap"]),
            bool(c["supervisor_repeat_actions"]),
            bool(c["supervisor_rear_avs"]),
            self.supervisor.emergency_brake,
            self.supervisor.joint_search,
            self.supervisor.brake_keeps_lane,
            bool(c["supervisor_mobil_safety"]),
            float(c["hdv_politeness"]),
            float(c["hdv_b_safe"]),
            float(c["hdv_lane_change_threshold"]),
            float(c["rule_acceleration_threshold"]),
            float(c["headway_max_distance"]),
            float(c["reward_speed_range"][0]),
            float(c["reward_speed_range"][1]),
            float(c["harsh_acceleration_threshold"]),
            int(c["obs_vehicles_count"]),
            self.road_length,
            float(c["obs_x_range"]),
            float(c["obs_y_range"]),
            float(c["obs_speed_range"]),
            bool(c["obs_target_speed"]),
            spawn_parameters(c, cfg.resolved_hdv_range(c, self.scenario), merge is not None),
            merge,
        )

    @property
    def road_length(self) -> float:
        """[m] the road's length, by which the observation normalises the ego's x."""
        return self._scenario_road.length

    @property
    def n_avs(self) -> int:
        """Number of AVs controlled by this instance (the config's, as of the last reset or configure)."""
        return self._n_avs

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
        """Spawn a new episode (:func:`~sb3_marl.sim.spawn.new_episode`, from :attr:`np_random`);
        ``options={"config": {...}}`` reconfigures first, as in highway-env."""
        gym.Env.reset(self, seed=seed)
        if options and "config" in options:
            self.configure(options["config"])
        if self.simulator not in SIMULATORS:
            raise ValueError(f"Invalid simulator={self.simulator!r}: expected one of {SIMULATORS}.")
        self.update_metadata()
        self._derive()  # a config changed in place since (highway-env's env.config[...] = ...)
        self.define_spaces()
        roads, k = self._roads, self._k
        generator = self._generator()
        if seed is not None:  # gymnasium's reset made a new generator: the road's words from now on
            roads.take(k, generator)
        if seed is not None and self._dropout_stream is not None:
            roads.copies.dropout_generators[k] = pcg64.read_state(np.random.default_rng([seed, self._dropout_stream]))
        self.steps, self.done, c = 0, False, roads.copies
        roads.read_lent()
        c.supervise[k] = bool(self.config["safety_supervisor"])
        if c.dropout[k] > 0:
            c.supervise[k] = pcg64.random(c.dropout_generators[k]) >= c.dropout[k]
        spawn = self._parameters.spawn
        n_hdvs, state = new_episode(c.generators[k], self.n_avs, spawn, spawn.merge_obstacles)
        roads.write_lent()
        self.n_hdvs, self.state = int(n_hdvs), state
        self._road = None
        obs, info = self._observe_start()
        if self.render_mode == "human":
            self.render()
        return obs, info

    def place(
        self, avs: Sequence[tuple[float, int, float]], hdvs: Sequence[tuple[float, int, float]] = ()
    ) -> tuple[np.ndarray, dict]:
        """Replace the traffic of a reset env by ``n_avs`` AVs and any HDVs at (x [m], lane, speed
        [m/s]), on their lane's centre (lane: the road's lane number), as a new episode's spawn
        would place them; returns the new observation and info. For hand-made situations (tests,
        figures)."""
        if len(avs) != self.n_avs:
            raise ValueError(f"Invalid avs: expected {self.n_avs} (x, lane, speed) tuples, got {len(avs)}.")
        x, lane, speed = np.array([*avs, *hdvs], dtype=np.float64).reshape(-1, 3).T
        if not all(0 <= number < len(self.horizon.lanes) for number in lane.tolist()):
            raise ValueError(f"Invalid lane in {lane.tolist()}: expected lane numbers 0..{len(self.horizon.lanes) - 1}.")
        y = lanes.centre_y(self.horizon.lanes, lane.astype(np.int64), x)
        self.n_hdvs = len(hdvs)
        vehicles = vehicle_state(self.config, x, lane, speed, self.n_avs, y=y)
        obstacles = self._parameters.spawn.merge_obstacles
        self.state = vehicles if obstacles is None else np.concatenate([vehicles, obstacles])
        return self._observe_start()

    @property
    def state(self) -> np.ndarray:
        """(vehicles, :data:`~sb3_marl.sim.kernel.COLUMNS`) the road's vehicles, the AVs first."""
        return self._roads.rows(self._k)

    @state.setter
    def state(self, state: np.ndarray) -> None:
        self._roads.set_rows(self._k, state)

    @property
    def steps(self) -> int:
        """Simulation frames of the current episode (highway-env's count; whole policy steps)."""
        return int(self._roads.copies.steps[self._k]) * self.horizon.frames_per_step

    @steps.setter
    def steps(self, frames: int) -> None:
        self._roads.copies.steps[self._k] = frames // self.horizon.frames_per_step

    @property
    def time(self) -> float:
        """[s] simulated time of the current episode."""
        return self.steps_done / self.config["policy_frequency"]

    @time.setter
    def time(self, time: float) -> None:
        self._roads.copies.steps[self._k] = round(time * self.config["policy_frequency"])

    @property
    def n_hdvs(self) -> int:
        """HDVs at the episode's start."""
        return int(self._roads.copies.n_hdvs[self._k])

    @n_hdvs.setter
    def n_hdvs(self, n_hdvs: int) -> None:
        self._roads.copies.n_hdvs[self._k] = n_hdvs

    @property
    def supervised(self) -> bool:
        """Whether the current episode runs the safety supervisor (the config's, or its dropout's draw)."""
        return bool(self._roads.copies.supervise[self._k])

    @property
    def np_random(self) -> np.random.Generator:
        """gymnasium's generator of the env: its road's episodes are drawn from it (a mirror of
        the road's generator words, :meth:`~sb3_marl.envs.roads.Roads.lend`)."""
        return self._roads.lend(self._k, self._generator())

    @np_random.setter
    def np_random(self, value: np.random.Generator) -> None:
        self._np_random, self._np_random_seed = value, -1  # as gymnasium's setter
        self._roads.take(self._k, value)

    def _generator(self) -> np.random.Generator:
        """gymnasium's generator of the env as it is, made with a random seed on first use (its
        state then the road's words)."""
        if self._np_random is None:
            self._np_random, self._np_random_seed = seeding.np_random()
            self._roads.take(self._k, self._np_random)
        return self._np_random

    @property
    def road(self) -> Road:
        """highway-env's road with :attr:`state`'s vehicles as objects, the AVs first."""
        if self._road is None:
            self._road = highway_env_road(self.config, self.scenario, self.np_random)
        if self._road_at != self._roads.changes:
            self._road.vehicles = vehicle_objects(self._road, self.state, self.config)
            self._road_at = self._roads.changes
        return self._road

    @road.setter
    def road(self, road: None) -> None:
        """Only highway-env's ``AbstractEnv.__init__`` sets it (to None): the road is built from :attr:`state`."""
        self._road = road

    @property
    def avs(self) -> list[MDPVehicle]:
        """The AVs as highway-env objects (the first vehicles of :attr:`road`)."""
        return self.road.vehicles[: self.n_avs]

    @property
    def controlled_vehicles(self) -> list[MDPVehicle]:
        """highway-env's name for the AVs (its viewer follows the first)."""
        return self.avs

    @controlled_vehicles.setter
    def controlled_vehicles(self, vehicles: list) -> None:
        """Only ``AbstractEnv.__init__`` sets it (to []): the AVs are the state's first rows."""

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Apply one meta-action per AV for 1 / policy_frequency s of simulation: one call of the
        compiled batch step (:func:`~sb3_marl.envs.batch_kernel.step_copies`, this road a batch of
        one), or highway-env's objects frame by frame where frames are drawn or the simulator is
        ``stock``."""
        if self.done:
            raise RuntimeError("The episode is over (terminated or truncated): call reset() before step().")
        n = self.n_avs
        proposed = meta_actions.check_actions(action, n)
        p = self._parameters
        roads, k = self._roads, self._k
        if roads.batched:
            raise RuntimeError(f"Scenario copy {k} is stepped by its batch (ParameterSharingVecEnv.step), not alone.")
        if self._uses_objects():
            result = self._step_objects(proposed, p, bool(roads.copies.supervise[k]), bool(roads.copies.shadow[k]))
        else:
            result, _ = step_copies(self.state, self._rows(), np.array([0, n]), proposed, roads.copies, p)
            self.state = result.states[: result.offsets[-1]]
        obs, info = self._report(result, proposed)
        terminated, truncated = bool(result.terminated[0]), bool(result.truncated[0])
        self.done = terminated or truncated
        if self.render_mode == "human":
            self.render()
        return obs, float(info["rewards"].sum()) / n, terminated, truncated, info

    def _rows(self) -> np.ndarray:
        """Where this road's rows start and end in its state (the batch-of-one's offsets)."""
        return np.array([0, len(self.state)], dtype=np.int64)

    def _step_objects(self, proposed: np.ndarray, p: StepParameters, supervise: bool, shadow: bool) -> BatchStep:
        """A step of highway-env's objects (:meth:`_simulate`), observed as the compiled step
        observes its own (:func:`~sb3_marl.envs.batch_kernel.observe_copies`)."""
        n, h = self.n_avs, self.horizon
        acting, braking, intervened = proposed, np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        if supervise or shadow:
            supervised, brake = supervise_road(self.state, n, proposed, p, p.merge)
            intervened = (supervised != proposed) | brake  # in shadow: where it would have
            if supervise:
                acting, braking = supervised, brake
        speed_before, targets_before = self.state[:n, kernel.SPEED].copy(), self.state[:n, kernel.TARGET_LANE].copy()
        self._simulate(acting, braking)
        self._roads.copies.steps[self._k] += 1
        state = self.state
        acceleration = (state[:n, kernel.SPEED] - speed_before) * self.config["policy_frequency"]
        changed = lanes.lane_changes(h.lanes, targets_before, state)
        result = observe_copies(state, self._rows(), np.array([0, n]), np.zeros(1, dtype=np.int64), acceleration, changed, p)
        result.executed[:], result.braking[:], result.intervened[:] = acting, braking, intervened
        result.terminated[0] = result.crashed.any()
        result.truncated[0] = not result.terminated[0] and (self.steps_done >= self.max_steps or result.exited.all())
        return result

    def _uses_objects(self) -> bool:
        """Whether highway-env's objects step the road frame by frame (drawn frames, or the stock reference)."""
        return self.simulator == STOCK or self.viewer is not None or bool(self.config["show_trajectories"])

    def _simulate(self, actions: np.ndarray, braking: np.ndarray) -> None:
        """Apply the executed meta-actions (target speed 0 m/s for the AVs ``braking``) to
        highway-env's objects and simulate the frames of one policy step with ``Road.act`` /
        ``Road.step`` (the frames in between drawn), captured into the state array after."""
        h = self.horizon
        road = self.road
        step_objects(road, [ACTIONS[int(a)] for a in actions], braking, h.frames_per_step, h.dt, h.road_end, self._frame)
        self.enable_auto_render = False
        self.state = capture(road.vehicles, road.network, road.objects)
        self._road_at = self._roads.changes  # the objects stepped are the state

    def _frame(self, frame: int) -> None:
        """After each simulated frame of the objects: draw the frames between policy steps."""
        if frame < self.horizon.frames_per_step - 1:
            self._automatic_rendering()

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
        return int(self._roads.copies.steps[self._k])

    def action_masks(self) -> np.ndarray:
        """(n_avs, 5) bool: which meta-actions are available to each AV.

        Same rule as highway-env's ``DiscreteMetaAction.get_available_actions``: IDLE always;
        a lane change only towards an existing lane reachable from the AV's position; FASTER /
        SLOWER unless the AV already tracks the highest / lowest target speed.
        """
        return meta_actions.available_actions(self.state, self.n_avs, self.horizon.lanes, self.horizon.ladder)

    def rule_actions(self) -> np.ndarray:
        """(n_avs,) int: the meta-action the scenario's human driver (IDM + MOBIL, the config's MOBIL
        parameters, aiming at ``speed_limit``) would pick in each AV's place now
        (:func:`~sb3_marl.sim.drivers.rule_actions`; the ``idm-mobil`` reference policy and the
        learners' rule prior)."""
        config = self.config
        return drivers.rule_actions(
            self.state,
            self.n_avs,
            None,
            self.horizon.lanes,
            self.horizon.ladder,
            float(config["speed_limit"]),
            float(config["hdv_politeness"]),
            float(config["hdv_b_safe"]),
            float(config["hdv_lane_change_threshold"]),
            float(config["rule_acceleration_threshold"]),
        )

    def _observe_start(self) -> tuple[np.ndarray, dict[str, Any]]:
        """The observation and info of a new situation: no acceleration or lane change, no action yet (-1)."""
        n = self.n_avs
        still, straight = np.zeros(n), np.zeros(n, dtype=bool)
        p = self._parameters
        result = observe_copies(self.state, self._rows(), np.array([0, n]), np.zeros(1, dtype=np.int64), still, straight, p)
        return self._report(result, np.full(n, -1, dtype=np.int64))

    def _report(self, result: BatchStep, proposed: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        """The observation (n_avs, vehicles, features) and the step's info, per-AV arrays of shape
        (n_avs,) unless stated.

        ``rewards`` (the weighted total), ``reward_terms`` (dict of unweighted terms, see
        :mod:`sb3_marl.envs.reward`), ``neighbours`` ((n_avs, n_avs) bool, the local reward's
        sets), ``crashed``, ``speed`` [m/s], ``headway`` [m], ``acceleration`` [m/s²],
        ``lane_change``, ``exited`` (past the road end), ``action_mask`` ((n_avs, 5) bool, for
        the next step), ``proposed_action`` (the policy's), ``executed_action`` (after the safety
        supervisor; both -1 after a reset), ``emergency_brake`` (the supervisor braked the AV to a
        stop), ``intervened`` (the supervisor replaced the action or braked; with
        ``supervisor_shadow`` and the supervisor off: would have),
        ``rule_action`` (the rule driver's meta-action in the new state, :meth:`rule_actions`),
        and the scalars ``n_avs``, ``n_hdvs``, ``step``.
        """
        n = self.n_avs
        arrays = step_report(result, proposed, self.config, self._parameters.merge is not None)
        info = {
            "rewards": arrays.pop("reward"),
            "reward_terms": arrays.pop("reward_terms"),
            "neighbours": result.neighbours[:, :n],
            **{key: arrays[key] for key in ("crashed", "speed", "headway", "acceleration", "lane_change", "exited")},
            **{key: arrays[key] for key in ("action_mask", "proposed_action", "executed_action")},
            "emergency_brake": result.braking,
            "intervened": arrays["intervened"],
            "rule_action": arrays["rule_action"],
            "n_avs": n,
            "n_hdvs": self.n_hdvs,
            "step": self.steps_done,
        }
        if self._parameters.merge is not None:
            self._merge_info(info)
        return result.obs, info

    def _merge_info(self, info: dict[str, Any]) -> None:
        """The merge's info: ``ramp_av`` (the AV started on the ramp), ``merge_time`` [s] (when a
        ramp AV reached the main road; NaN: not yet) and ``stranded`` (vehicles at a standstill,
        under 1 m/s, on the merging lane)."""
        state, n, roads, slots = self.state, self.n_avs, self._roads, self._roads.slots(self._k)
        lane = state[:n, kernel.LANE].astype(np.int64)
        if self.steps == 0:  # a new situation (reset, place)
            roads.new_situation(slots, lane)
        else:
            roads.record_merges(slots, lane, np.full(n, self.steps_done), self.config["policy_frequency"])
        info["ramp_av"], info["merge_time"] = roads.ramp_av[slots].copy(), roads.merge_time[slots].copy()
        on_merging_lane = state[:, kernel.LANE] == MERGING_LANE
        stranded = on_merging_lane & (state[:, kernel.SPEED] < 1.0) & (state[:, kernel.IS_OBSTACLE] == 0)
        info["stranded"] = int(np.count_nonzero(stranded))
