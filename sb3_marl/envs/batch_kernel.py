"""The compiled step of every copy of a scenario at once (:func:`step_copies`), for
:class:`~sb3_marl.envs.batch.RoadBatch`.

The copies' state arrays (the kernel's layout, AVs first) lie one after the other in one array,
copy k's rows at ``offsets[k]:offsets[k + 1]``; the AV slots of all copies likewise, copy k's at
``slot_starts[k]:slot_starts[k + 1]``. For every copy, one call does what
:meth:`LaneChangeEnv.step <sb3_marl.envs.lane_change_env.LaneChangeEnv.step>` does for one (the
merge's differences switched by :class:`StepParameters`' ``merge``) — the safety supervisor, the
frames of the policy step, observations, reward terms, neighbour sets, action masks and the rule
driver's actions — with the same compiled functions. The merge's functions are compiled only for
the merge: the parameters' ``merge`` (None on the highway) reaches them as an argument, and numba
compiles only the branch of its type. Units: m, m/s, m/s², s, Hz.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from sb3_marl.envs.merge_rules import MergeRules, _merge_priorities, _regional_neighbours
from sb3_marl.envs.observation import _observe
from sb3_marl.envs.reward import REWARD_MODES, _neighbour_matrix, _terms, mode_rewards, reward_terms, total_reward
from sb3_marl.safety.rooms import SLOWER, Horizon
from sb3_marl.safety.supervisor import headway_margins, supervise_arrays
from sb3_marl.sim import kernel, pcg64
from sb3_marl.sim.drivers import rule_actions
from sb3_marl.sim.dynamics import policy_step
from sb3_marl.sim.kernel import jit
from sb3_marl.sim.lanes import lane_changes
from sb3_marl.sim.merge_road import ENDS, MERGE_END, MERGING_LANE
from sb3_marl.sim.meta_actions import available_actions, meta_action_targets
from sb3_marl.sim.spawn import SpawnParameters, new_episode

#: The global reward mode's index (each slot's copy's mean reward).
GLOBAL = REWARD_MODES.index("global")


class StepParameters(NamedTuple):
    """What a step reads from the scenario config (compiled code takes it as one argument)."""

    horizon: Horizon
    policy_frequency: float  # [Hz]
    max_steps: int  # policy steps of a full episode
    headway_time: float  # [s]
    min_gap: float  # [m], the supervisor's
    repeat_actions: bool
    rear_avs: bool
    emergency_brake: bool
    joint_search: bool
    brake_keeps_lane: bool
    mobil_safety: bool
    politeness: float  # the rule driver's MOBIL parameters
    b_safe: float  # [m/s²]
    lane_change_threshold: float  # [m/s²]
    rule_acceleration_threshold: float  # [m/s²]
    headway_max_distance: float  # [m]
    v_min: float  # [m/s], reward_speed_range
    v_max: float  # [m/s]
    harsh_threshold: float  # [m/s²]
    rows: int  # observed vehicles
    road_length: float  # [m]
    x_range: float  # [m]
    y_range: float  # [m]
    v_range: float  # [m/s]
    target_speed_column: bool
    spawn: SpawnParameters  # a new episode's traffic
    # the merge's neighbour sets and supervisor order (sb3_marl.envs.merge_env), None on the highway;
    # compiled callees receive it as an argument, p.merge (see the module doc)
    merge: MergeRules | None


class BatchStep(NamedTuple):
    """One step of every copy: arrays over the AV slots (copy by copy, AVs in order) unless stated."""

    states: np.ndarray  # (rows, COLUMNS) the copies' new states, one after the other
    offsets: np.ndarray  # (copies + 1,) where each copy's rows start
    obs: np.ndarray  # (slots, vehicles, features) float32
    terms: np.ndarray  # (7, slots) reward.REWARD_TERMS then the headway distance [m]; headway as d / (v t_d)
    neighbours: np.ndarray  # (slots, max AVs) bool, column j: AV j of the slot's copy
    crashed: np.ndarray
    exited: np.ndarray
    speed: np.ndarray  # [m/s]
    acceleration: np.ndarray  # [m/s²]
    lane_change: np.ndarray
    action_mask: np.ndarray  # (slots, 5) bool, of the new observation
    executed: np.ndarray  # int
    braking: np.ndarray  # bool, the supervisor's emergency brake
    intervened: np.ndarray  # bool
    rule_action: np.ndarray  # int, in the new state
    x: np.ndarray  # [m] each AV's position after the step
    lane: np.ndarray  # int, each AV's lane after the step
    terminated: np.ndarray  # (copies,) bool: an AV crashed
    truncated: np.ndarray  # (copies,) bool: the time limit, or every AV past the road end


@jit
def _allocate(states: np.ndarray, offsets: np.ndarray, slot_starts: np.ndarray, p: StepParameters) -> BatchStep:
    """A :class:`BatchStep` of the copies' slots: no action yet (-1), nothing moved or crashed."""
    n_copies, slots = offsets.size - 1, slot_starts[-1]
    max_avs = 0
    for k in range(n_copies):
        max_avs = max(max_avs, slot_starts[k + 1] - slot_starts[k])
    features = 6 if p.target_speed_column else 5
    return BatchStep(
        states,
        offsets,
        np.zeros((slots, p.rows, features), dtype=np.float32),
        np.ones((7, slots)),  # (a headway ratio of 1: a log of 0 where nothing is observed)
        np.zeros((slots, max_avs), dtype=np.bool_),
        np.zeros(slots, dtype=np.bool_),
        np.zeros(slots, dtype=np.bool_),
        np.zeros(slots),
        np.zeros(slots),
        np.zeros(slots, dtype=np.bool_),
        np.zeros((slots, 5), dtype=np.bool_),
        np.full(slots, -1, dtype=np.int64),
        np.zeros(slots, dtype=np.bool_),
        np.zeros(slots, dtype=np.bool_),
        np.zeros(slots, dtype=np.int64),
        np.zeros(slots),
        np.zeros(slots, dtype=np.int64),
        np.zeros(n_copies, dtype=np.bool_),
        np.zeros(n_copies, dtype=np.bool_),
    )


class CopyState(NamedTuple):
    """Each copy's episode so far, arrays over the copies that a step changes in place."""

    steps: np.ndarray  # int, the episode's policy steps
    supervise: np.ndarray  # bool, the safety supervisor on (the episode's draw with a dropout)
    shadow: np.ndarray  # bool, the supervisor only reports (supervisor_shadow)
    n_hdvs: np.ndarray  # int, the episode's HDVs at its spawn
    generators: np.ndarray  # (copies, 6) uint64, the spawn's generator (sb3_marl.sim.pcg64: the env's np_random)
    dropout_generators: np.ndarray  # (copies, 6) uint64, the supervisor dropout's generator
    dropout: np.ndarray  # float, probability that an episode runs without the supervisor (0: as configured)


class Starts(NamedTuple):
    """Where the next step starts, arrays over the AV slots: the new episode's first observation
    where the copy ``restarted``, else the step's own."""

    obs: np.ndarray  # (slots, vehicles, features) float32
    action_mask: np.ndarray  # (slots, 5) bool
    rule_action: np.ndarray  # int
    lane: np.ndarray  # int, each AV's lane
    restarted: np.ndarray  # (copies,) bool: the copy's episode ended and a new one began


@jit
def _step_copies(
    states: np.ndarray,
    offsets: np.ndarray,
    slot_starts: np.ndarray,
    actions: np.ndarray,
    c: CopyState,
    p: StepParameters,
    respawn: bool,
) -> tuple:
    """:func:`step_copies`'s fields."""
    h = p.horizon
    n_copies = offsets.size - 1
    rows = 0  # room for every copy's state, a new episode's as large as it may be
    for k in range(n_copies):
        spawned = slot_starts[k + 1] - slot_starts[k] + p.spawn.hdv_high + p.spawn.n_obstacles
        rows += max(offsets[k + 1] - offsets[k], spawned)
    r = _allocate(np.empty((rows, states.shape[1])), np.zeros(n_copies + 1, dtype=np.int64), slot_starts, p)
    first = _allocate(r.states, r.offsets, slot_starts, p)
    restarted = np.zeros(n_copies, dtype=np.bool_)
    for k in range(n_copies):
        a, b = slot_starts[k], slot_starts[k + 1]
        n = b - a
        before = states[offsets[k] : offsets[k + 1]]
        proposed = actions[a:b]
        acting, brake = proposed.copy(), np.zeros(n, dtype=np.bool_)
        if c.supervise[k] or c.shadow[k]:
            supervised, brake_to_stop = supervise_road(before, n, proposed, p, p.merge)
            r.intervened[a:b] = (supervised != proposed) | brake_to_stop
            if c.supervise[k]:
                acting, brake = supervised, brake_to_stop
        r.executed[a:b], r.braking[a:b] = acting, brake
        speed_before, targets_before = before[:n, kernel.SPEED].copy(), before[:n, kernel.TARGET_LANE].copy()
        state = policy_step(before, acting, h.frames_per_step, h.dt, h.lanes, h.road_end, h.speed_limit, h.ladder, brake)
        c.steps[k] += 1
        r.acceleration[a:b] = (state[:n, kernel.SPEED] - speed_before) * p.policy_frequency
        r.lane_change[a:b] = lane_changes(h.lanes, targets_before, state)
        _observe_into(r, state, a, b, p, p.merge, True)
        r.terminated[k] = r.crashed[a:b].any()
        r.truncated[k] = not r.terminated[k] and (c.steps[k] >= p.max_steps or r.exited[a:b].all())
        if respawn and (r.terminated[k] or r.truncated[k]):  # as the env's reset, from its generator
            if c.dropout[k] > 0:
                c.supervise[k] = pcg64.random(c.dropout_generators[k]) >= c.dropout[k]
            c.n_hdvs[k], state = new_episode(c.generators[k], n, p.spawn, p.spawn.merge_obstacles)
            c.steps[k] = 0
            restarted[k] = True
            _observe_into(first, state, a, b, p, p.merge, False)
        else:  # on every path, also without respawn (a path without it keeps numba's reference counts: kernel.jit)
            first.obs[a:b], first.action_mask[a:b] = r.obs[a:b], r.action_mask[a:b]
            first.rule_action[a:b], first.lane[a:b] = r.rule_action[a:b], r.lane[a:b]
        r.offsets[k + 1] = r.offsets[k] + state.shape[0]
        r.states[r.offsets[k] : r.offsets[k + 1]] = state
    return _fields(r), (first.obs, first.action_mask, first.rule_action, first.lane, restarted)


@jit
def _observe_copies(
    states: np.ndarray,
    offsets: np.ndarray,
    slot_starts: np.ndarray,
    copies: np.ndarray,
    acceleration: np.ndarray,
    lane_change: np.ndarray,
    p: StepParameters,
) -> tuple:
    """:func:`observe_copies`'s fields."""
    r = _allocate(states, offsets, slot_starts, p)
    for k in copies:
        a, b = slot_starts[k], slot_starts[k + 1]
        r.acceleration[a:b], r.lane_change[a:b] = acceleration[a:b], lane_change[a:b]
        _observe_into(r, states[offsets[k] : offsets[k + 1]], a, b, p, p.merge, True)
    return _fields(r)


@jit
def _fields(r: BatchStep) -> tuple:
    """``r``'s fields as a plain tuple: returning a named tuple to Python runs its constructor in
    Python, where a signal's KeyboardInterrupt would land inside numba's boxing and crash it."""
    return (
        r.states,
        r.offsets,
        r.obs,
        r.terms,
        r.neighbours,
        r.crashed,
        r.exited,
        r.speed,
        r.acceleration,
        r.lane_change,
        r.action_mask,
        r.executed,
        r.braking,
        r.intervened,
        r.rule_action,
        r.x,
        r.lane,
        r.terminated,
        r.truncated,
    )


def step_copies(
    states: np.ndarray,
    offsets: np.ndarray,
    slot_starts: np.ndarray,
    actions: np.ndarray,
    copies: CopyState,
    p: StepParameters,
    respawn: bool = False,
) -> tuple[BatchStep, Starts]:
    """One policy step of every copy (see the module doc), ``copies`` advanced in place. With
    ``respawn``, a copy whose episode ended begins a new one in the same call, as its env's reset
    would (its HDV count and spawn drawn from its generator, the supervisor's dropout from its
    own): the step's ``states`` then hold the new episode, its observations the ended one's last,
    and the :class:`Starts` (where the next step starts) the new episode's first."""
    step, starts = _step_copies(states, offsets, slot_starts, actions, copies, p, respawn)
    return BatchStep(*step), Starts(*starts)


def observe_copies(
    states: np.ndarray,
    offsets: np.ndarray,
    slot_starts: np.ndarray,
    copies: np.ndarray,
    acceleration: np.ndarray,
    lane_change: np.ndarray,
    p: StepParameters,
) -> BatchStep:
    """The observation of ``copies``' states and what a step reports of it, their AVs having
    changed speed by ``acceleration`` [m/s²] and changed lane where ``lane_change`` (zeros: a new
    episode's first observation; else a step that highway-env's objects simulated); the other
    copies' slots are left empty."""
    return BatchStep(*_observe_copies(states, offsets, slot_starts, copies, acceleration, lane_change, p))


@jit
def _observe_into(
    r: BatchStep, state: np.ndarray, a: int, b: int, p: StepParameters, merge: MergeRules | None, rewarded: bool
) -> None:
    """Write the observation of one copy's ``state`` (its AVs at slots ``a:b``) into ``r``, with its
    action masks, the rule driver's actions and, where ``rewarded``, its reward terms and
    neighbour sets (``r``'s acceleration and lane changes of the slots already set; a new
    episode's first observation in a step has no reward). ``merge`` is ``p.merge`` (see the
    module doc)."""
    h, n = p.horizon, b - a
    x, heading = state[:, kernel.X], state[:, kernel.HEADING]
    v = state[:, kernel.SPEED]
    lane = state[:, kernel.LANE].astype(np.int64)
    visible = (x <= h.road_end) & (state[:, kernel.IS_OBSTACLE] == 0)
    r.crashed[a:b] = state[:n, kernel.CRASHED] > 0
    r.exited[a:b] = state[:n, kernel.COLLIDABLE] == 0
    r.speed[a:b] = v[:n]
    r.x[a:b], r.lane[a:b] = x[:n], lane[:n]
    mask = available_actions(state, n, h.lanes, h.ladder)
    r.action_mask[a:b] = mask
    r.rule_action[a:b] = rule_actions(
        state,
        n,
        mask,
        h.lanes,
        h.ladder,
        h.speed_limit,
        p.politeness,
        p.b_safe,
        p.lane_change_threshold,
        p.rule_acceleration_threshold,
    )
    vx, vy = v * np.cos(heading), v * np.sin(heading)
    y = state[:, kernel.Y]
    r.obs[a:b, :, :5] = _observe(x, y, vx, vy, visible, n, p.rows, p.road_length, p.x_range, p.y_range, p.v_range)
    if p.target_speed_column:
        for i in range(n):
            r.obs[a + i, 0, 5] = np.float32(min(max(state[i, kernel.TARGET_SPEED] / p.v_range, -1.0), 1.0))
    if not rewarded:
        return
    r.terms[:, a:b] = _terms(
        x,
        lane,
        visible,
        v,
        n,
        r.crashed[a:b],
        r.acceleration[a:b],
        r.lane_change[a:b],
        p.headway_max_distance,
        p.headway_time,
        p.v_min,
        p.v_max,
        p.harsh_threshold,
    )
    if merge is None:
        r.neighbours[a:b, :n] = _neighbour_matrix(x, lane, visible, n)
    else:
        r.neighbours[a:b, :n] = _regional_neighbours(state, n, merge.route, merge.across, merge.across_from)


@jit
def supervise_road(
    state: np.ndarray, n: int, proposed: np.ndarray, p: StepParameters, merge: MergeRules | None
) -> tuple[np.ndarray, np.ndarray]:
    """:class:`~sb3_marl.safety.supervisor.Supervisor` of a copy (priority: the headway margin, or
    the merge's): the executed meta-actions and which AVs brake to a stop. ``merge`` is ``p.merge``
    (see the module doc)."""
    h = p.horizon
    candidate_lane, candidate_speed = meta_action_targets(state, n, h.lanes, h.ladder)
    choices = available_actions(state, n, h.lanes, h.ladder)
    if p.emergency_brake:
        for i in range(n):
            choices[i, SLOWER] |= state[i, kernel.TARGET_SPEED] < h.ladder[0]
    if merge is not None and merge.merging_priority:
        priority = _merge_priorities(state, n, p.headway_time, merge.next_on_route)
    else:
        priority = headway_margins(state, n, h.lanes, p.headway_time)
    executed, _, brake = supervise_arrays(
        state,
        candidate_lane,
        candidate_speed,
        choices,
        proposed,
        priority,
        h,
        p.min_gap,
        p.repeat_actions,
        p.rear_avs,
        p.emergency_brake,
        p.joint_search,
        p.mobil_safety,
        p.brake_keeps_lane,
    )
    return executed, brake


@jit
def copy_rewards(own: np.ndarray, neighbours: np.ndarray, slot_starts: np.ndarray, mode: int) -> tuple[np.ndarray, np.ndarray]:
    """Every slot's reward in a reward mode (:data:`~sb3_marl.envs.reward.REWARD_MODES` index) and
    its copy's mean reward (the ``global`` mode's), copy by copy."""
    rewards, means = np.empty(own.size), np.empty(own.size)
    for k in range(slot_starts.size - 1):
        a, b = slot_starts[k], slot_starts[k + 1]
        rewards[a:b] = mode_rewards(own[a:b], neighbours[a:b, : b - a], mode)
        means[a:b] = mode_rewards(own[a:b], neighbours[a:b, : b - a], GLOBAL)
    return rewards, means


def step_report(result: BatchStep, proposed: np.ndarray, config: dict[str, Any], merge: bool) -> dict[str, Any]:
    """The per-slot arrays of a step, named as the scenario's info entries: the driving metrics,
    masks, actions and interventions of ``result``, each AV's own weighted reward (``reward``) and
    its unweighted terms (``reward_terms``, with the merge's merging-lane cost where ``merge``)."""
    names = reward_terms(result.terms)
    headway = names.pop("headway_distance")
    own = total_reward(names, config)
    if merge:  # MARL_CAVs' merging-lane cost: -exp(-(x - merge end)² / (10 × merging lane length))
        cost = -np.exp(-((result.x - MERGE_END) ** 2) / (10 * ENDS[2]))
        names["merging_lane"] = np.where(result.lane == MERGING_LANE, cost, 0.0)
        own = own + config["merging_lane_weight"] * names["merging_lane"]
    return {
        "speed": result.speed,
        "headway": headway,
        "acceleration": result.acceleration,
        "lane_change": result.lane_change,
        "crashed": result.crashed,
        "exited": result.exited,
        "action_mask": result.action_mask,
        "proposed_action": proposed,
        "executed_action": result.executed,
        "intervened": result.intervened,
        "rule_action": result.rule_action,
        "reward": own,
        "reward_terms": names,
    }
