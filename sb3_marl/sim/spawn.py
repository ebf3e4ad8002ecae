"""A new episode's traffic, drawn in compiled code (:func:`new_episode`): the HDV count, then the
lane change's grid spawn or the merge's spawn points, from a generator state of
:mod:`~sb3_marl.sim.pcg64` (NumPy's draws: a scenario env's ``np_random`` spawns the same episode
here as in Python). Units: m, m/s.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from sb3_marl.sim import HDV_STYLES, pcg64
from sb3_marl.sim.kernel import jit
from sb3_marl.sim.merge_road import MAIN_BEFORE, MAIN_SPAWN, RAMP, RAMP_SPAWN, RAMP_Y, obstacle_rows
from sb3_marl.sim.road import vehicle_rows


class SpawnParameters(NamedTuple):
    """What a spawn reads from the scenario config (compiled code takes it as one argument, and
    ``merge_obstacles`` once more on its own: :func:`new_episode`)."""

    lanes_count: int  # the highway's grid: lanes_count × slots_per_lane slots
    slots_per_lane: int
    start: float  # [m] the grid's first slot
    spacing: float  # [m] between a lane's slots
    lane_width: float  # [m]
    position_noise: float  # [m] uniform jitter ± of each position
    speed_low: float  # [m/s] uniform initial speeds
    speed_high: float  # [m/s]
    hdv_low: int  # the HDV count's inclusive range
    hdv_high: int
    ladder: np.ndarray  # [m/s] the AVs' target speeds
    politeness: float  # the HDVs' MOBIL parameters
    b_safe: float  # [m/s²]
    min_acc_gain: float  # [m/s²]
    hdv_idm: np.ndarray  # the HDVs' IDM style (sb3_marl.sim.HDV_STYLES)
    n_obstacles: int  # rows after the vehicles' (the merge's end of the merging lane)
    # (n_obstacles, COLUMNS) the merge's obstacle rows, None on the highway: not None selects the
    # merge's spawn points (sb3_marl.sim.merge_road), None the highway's grid (new_episode)
    merge_obstacles: np.ndarray | None


def spawn_parameters(config: dict[str, Any], hdv_range: tuple[int, int], merge: bool) -> SpawnParameters:
    """The spawn of a scenario ``config`` with HDV counts in ``hdv_range`` (inclusive) on the merge's
    road (``merge``) or the highway."""
    obstacles = obstacle_rows() if merge else None
    return SpawnParameters(
        int(config.get("lanes_count", 1)),
        int(config.get("spawn_slots_per_lane", 1)),
        float(config.get("spawn_start", 0.0)),
        float(config.get("spawn_spacing", 0.0)),
        float(config.get("lane_width", 4.0)),
        float(config["spawn_position_noise"]),
        float(config["spawn_speed_range"][0]),
        float(config["spawn_speed_range"][1]),
        int(hdv_range[0]),
        int(hdv_range[1]),
        np.asarray(config["target_speeds"], dtype=np.float64),
        float(config["hdv_politeness"]),
        float(config["hdv_b_safe"]),
        float(config["hdv_lane_change_threshold"]),
        np.array(HDV_STYLES[config.get("hdv_style", "normal")], dtype=np.float64),
        0 if obstacles is None else len(obstacles),
        obstacles,
    )


def draw_episode(np_random: np.random.Generator, n_avs: int, s: SpawnParameters) -> tuple[int, np.ndarray]:
    """:func:`new_episode` drawn from a NumPy generator (advanced as if it had drawn itself)."""
    words = pcg64.read_state(np_random)
    n_hdvs, state = new_episode(words, n_avs, s, s.merge_obstacles)
    pcg64.write_state(np_random, words)
    return int(n_hdvs), state


@jit
def new_episode(g: np.ndarray, n_avs: int, s: SpawnParameters, merge_obstacles: np.ndarray | None) -> tuple[int, np.ndarray]:
    """A new episode from the generator state ``g`` (advanced): its HDV count, uniform in
    ``s``'s range, and its state array (the ``n_avs`` AVs first, then the HDVs and obstacles).
    ``merge_obstacles`` is ``s.merge_obstacles`` as an argument: numba compiles only the branch of
    its type (None: the highway's grid)."""
    n_hdvs = pcg64.integers(g, s.hdv_low, s.hdv_high + 1)
    if merge_obstacles is None:
        return n_hdvs, _grid_spawn(g, n_avs, n_hdvs, s)
    return n_hdvs, _merge_spawn(g, n_avs, n_hdvs, s, merge_obstacles)


@jit
def _grid_spawn(g: np.ndarray, n_avs: int, n_hdvs: int, s: SpawnParameters) -> np.ndarray:
    """The highway's spawn: every vehicle in a distinct random slot of a grid along every lane,
    ``spacing`` m apart from ``start``, jittered by up to ``position_noise`` m (validation keeps the
    spacing above the 5 m vehicle length plus twice the noise: no overlap); speeds uniform."""
    slots = pcg64.choice(g, s.lanes_count * s.slots_per_lane, n_avs + n_hdvs)
    noise = pcg64.uniform(g, -1.0, 1.0, slots.size) * s.position_noise
    speeds = pcg64.uniform(g, s.speed_low, s.speed_high, slots.size)
    x = s.start + (slots % s.slots_per_lane) * s.spacing + noise
    lane = (slots // s.slots_per_lane).astype(np.float64)
    return _vehicles(x, lane * s.lane_width, lane, speeds, n_avs, s)


@jit
def _merge_spawn(g: np.ndarray, n_avs: int, n_hdvs: int, s: SpawnParameters, obstacles: np.ndarray) -> np.ndarray:
    """The merge's spawn, as MARL_CAVs' ``merge_env_v1._make_vehicles`` draws it: half the AVs
    (rounded down) at distinct random spawn points of the main road, the others on the ramp, then
    half the HDVs (rounded down) at the main road's remaining points and the others at the ramp's;
    positions jittered by ``position_noise`` m, speeds uniform. Rows: the AVs, the HDVs, the obstacle."""
    main, ramp = np.array(MAIN_SPAWN), np.array(RAMP_SPAWN)
    main_avs = pcg64.choice(g, main.size, n_avs // 2)
    ramp_avs = pcg64.choice(g, ramp.size, n_avs - n_avs // 2)
    main_left, ramp_left = _left(main.size, main_avs), _left(ramp.size, ramp_avs)
    main_hdvs = main_left[pcg64.choice(g, main_left.size, n_hdvs // 2)]
    ramp_hdvs = ramp_left[pcg64.choice(g, ramp_left.size, n_hdvs - n_hdvs // 2)]
    n = n_avs + n_hdvs
    speeds = pcg64.uniform(g, s.speed_low, s.speed_high, n)
    noise = pcg64.uniform(g, -1.0, 1.0, n) * s.position_noise
    x, y, lane = np.empty(n), np.zeros(n), np.full(n, float(MAIN_BEFORE))
    k = 0
    for group, positions in enumerate((main[main_avs], ramp[ramp_avs], main[main_hdvs], ramp[ramp_hdvs])):
        for position in positions:
            x[k] = position + noise[k]
            if group % 2:  # the ramp's
                y[k], lane[k] = RAMP_Y, float(RAMP)
            k += 1
    return np.concatenate((_vehicles(x, y, lane, speeds, n_avs, s), obstacles))


@jit
def _left(points: int, taken: np.ndarray) -> np.ndarray:
    """The spawn points of ``points`` not ``taken``, in order."""
    free = np.ones(points, dtype=np.bool_)
    free[taken] = False
    return np.flatnonzero(free)


@jit
def _vehicles(x: np.ndarray, y: np.ndarray, lane: np.ndarray, speed: np.ndarray, n_avs: int, s: SpawnParameters) -> np.ndarray:
    """The state rows of vehicles at (x, y) [m] on ``lane`` at ``speed`` [m/s] (:func:`~sb3_marl.sim.road.vehicle_state`)."""
    return vehicle_rows(x, y, lane, speed, n_avs, s.ladder, s.politeness, s.b_safe, s.min_acc_gain, s.hdv_idm)
