"""Configuration of the scenarios (the lane change, :data:`LANE_CHANGE`, and the on-ramp merge,
:data:`MERGE`): defaults, traffic densities and validation.

Every key is in SI units (m, m/s, m/s², s, Hz) and named after its unit where it helps.
A user's config is a plain dict merged over :func:`default_config`; :func:`validate_config`
checks the merged dict once and raises a single ``ValueError`` that names the key, the value
and what is allowed.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import Any

from sb3_marl.common.checks import is_integer, is_number
from sb3_marl.safety.supervisor import MERGE_SUPERVISOR_VERSIONS, SUPERVISOR_VERSIONS
from sb3_marl.sim import HDV_STYLES, LANE_CHANGE, MERGE

#: Traffic densities of the paper: inclusive (min, max) counts of AVs and of HDVs per episode.
DENSITIES: dict[int, dict[str, tuple[int, int]]] = {
    1: {"avs": (1, 3), "hdvs": (1, 3)},
    2: {"avs": (2, 4), "hdvs": (2, 4)},
    3: {"avs": (4, 6), "hdvs": (4, 6)},
}
#: Traffic densities of the merging paper (Chen et al. 2021; MARL_CAVs' ``merge_env_v1``).
MERGE_DENSITIES: dict[int, dict[str, tuple[int, int]]] = {
    1: {"avs": (1, 3), "hdvs": (1, 3)},
    2: {"avs": (2, 4), "hdvs": (2, 4)},
    3: {"avs": (4, 6), "hdvs": (3, 5)},
}
#: The scenarios and their densities.
SCENARIO_DENSITIES = {LANE_CHANGE: DENSITIES, MERGE: MERGE_DENSITIES}
#: Keys of the lane-change highway's road and spawn grid (the merge road is fixed: sb3_marl/sim/merge_road.py).
HIGHWAY_KEYS = ("road_length", "lanes_count", "lane_width", "spawn_start", "spawn_spacing", "spawn_slots_per_lane")
#: Keys of the merge scenario only.
MERGE_KEYS = ("merging_lane_weight", "supervisor_priority")
#: The safety supervisor's order of service on the merge road: MARL_CAVs' (the merging lane first,
#: by distance to its end, then by headway) or the lane change's (the smallest headway margin first).
SUPERVISOR_PRIORITIES = ("merging", "headway")

#: Highway-env's rendering keys that the scenario keeps (used by ``EnvViewer``).
RENDER_DEFAULTS: dict[str, Any] = {
    "screen_width": 1200,  # [px]
    "screen_height": 120,  # [px]
    "centering_position": [0.3, 0.5],
    "scaling": 3.0,  # [px/m]
    "show_trajectories": False,
    "render_agent": True,
    "offscreen_rendering": None,
    "manual_control": False,
    "real_time_rendering": False,
}


def default_config() -> dict[str, Any]:
    """The scenario of the paper, with the MARL_CAVs merging code's choices where the paper is silent."""
    return {
        # Traffic
        "density": 1,  # 1, 2 or 3 (see DENSITIES)
        "n_avs": None,  # AVs controlled by this instance; None -> the density's maximum
        "hdv_count_range": None,  # [min, max] HDVs sampled per reset; None -> the density's range
        # Road
        "road_length": 520.0,  # [m]; vehicles beyond it are ignored (see LaneChangeEnv)
        "lanes_count": 2,
        "lane_width": 4.0,  # [m]
        "speed_limit": 30.0,  # [m/s], caps the HDVs' IDM desired speed
        # Spawn: slots on a grid along each lane, a random subset filled each reset
        "spawn_start": 10.0,  # [m] position of the first slot
        "spawn_spacing": 40.0,  # [m] between slots of a lane
        "spawn_position_noise": 1.5,  # [m] uniform noise +- on each slot position
        "spawn_slots_per_lane": 6,
        "spawn_speed_range": [25.0, 30.0],  # [m/s] uniform initial speed of every vehicle
        # Timing
        "simulation_frequency": 15,  # [Hz]
        "policy_frequency": 5,  # [Hz]
        "duration": 20.0,  # [s] -> duration * policy_frequency policy steps
        # AV actions (highway-env DiscreteMetaAction)
        "target_speeds": [10.0, 15.0, 20.0, 25.0, 30.0],  # [m/s] set-points of FASTER/SLOWER
        # HDVs: highway-env IDMVehicle (IDM) with MOBIL lane changes
        "hdv_politeness": 0.0,  # MOBIL politeness p in [0, 1]
        "hdv_style": "normal",  # IDM car following: normal (highway-env's), timid or aggressive (sim.HDV_STYLES)
        "hdv_b_safe": 9.0,  # [m/s²] MOBIL maximum braking imposed on the new follower
        "hdv_lane_change_threshold": 0.1,  # [m/s²] MOBIL acceleration gain threshold
        # Observation: ego row + the nearest (vehicles_count - 1) vehicles
        "obs_vehicles_count": 5,
        "obs_x_range": 150.0,  # [m] normalisation and perception range of relative x
        "obs_y_range": 12.0,  # [m] normalisation of y
        "obs_speed_range": 45.0,  # [m/s] normalisation of vx, vy
        "obs_target_speed": False,  # True: a 6th feature, the ego's target speed, on its row (not the paper's)
        # Reward: w_s*r_s + w_d*r_d + w_v*r_v - w_c*r_c
        "safety_weight": 200.0,
        "headway_weight": 4.0,
        "speed_weight": 1.0,
        "comfort_weight": 1.0,
        "comfort": True,  # False drops the comfort term (the paper's ablation)
        "headway_time": 1.2,  # [s] t_d
        "headway_max_distance": 60.0,  # [m] headway used when no leader is nearer
        "reward_speed_range": [10.0, 30.0],  # [m/s] (v_min, v_max) of r_v
        "harsh_acceleration_threshold": 3.0,  # [m/s²] a_th: |a| >= a_th is harsh
        # Safety supervisor of the authors' MA2C (sb3_marl/safety/supervisor.py); on in the zoo configs
        "safety_supervisor": False,
        "supervisor_horizon": 1.4,  # [s] prediction horizon (7 policy steps at 5 Hz)
        "supervisor_min_gap": 2.0,  # [m] smallest predicted bumper-to-bumper gap accepted
        "supervisor_repeat_actions": True,  # AVs repeat their action at each step of the horizon
        # False: an AV's room leaves out the AVs following it in its own lane (they are served
        # themselves and brake for it), so that it may brake behind a slower vehicle; True (v3):
        # every vehicle counts, and a platoon of AVs behind a slower HDV holds its speed
        "supervisor_rear_avs": True,
        # the supervisor's decisions by version (sb3_marl.safety.supervisor.SUPERVISOR_VERSIONS):
        # 3 (the paper's numbers: results/supervisor-v3) has the emergency brake and the joint
        # search below off; 4 (the merge's default) has both on; 5 is 4 where an AV braked to a stop
        # starts no lane change; 6 (the lane change's default) is 5 predicting a policy step at a time
        "supervisor_version": 6,
        # when no meta-action leaves an AV supervisor_min_gap of room, brake it to a stop (a target
        # speed of 0 m/s, below the speed ladder) if that leaves more; a braked AV may then be
        # released by the supervisor with SLOWER (to the ladder's lowest speed); null: as
        # supervisor_version says
        "supervisor_emergency_brake": None,
        # when AVs are still short of supervisor_min_gap of room after the passes, search their
        # actions in pairs with the other AVs' (the whole road predicted for each pair); null: as
        # supervisor_version says
        "supervisor_joint_search": None,
        # an AV's lane change counts as short of room when its new follower, an HDV on the target
        # lane or on the lane leading into it, would brake harder behind it (IDM) than its MOBIL
        # safe braking (hdv_b_safe): the check MOBIL makes for the HDVs' own lane changes (the
        # merge's HDVs see no vehicle past the start of the lane they are about to enter)
        "supervisor_mobil_safety": False,
        # supervisor off: report in info["intervened"] where it would have replaced or braked an
        # action (nothing applied), so training's intervention penalty reaches those episodes
        "supervisor_shadow": False,
        # Rule driver (IDM/MOBIL as meta-actions, info["rule_action"]): FASTER / SLOWER when IDM's
        # acceleration is above / below +- this threshold
        "rule_acceleration_threshold": 1.0,  # [m/s²]
        **RENDER_DEFAULTS,
    }


def merge_default_config() -> dict[str, Any]:
    """The on-ramp merging scenario of MARL_CAVs' ``merge_env_v1`` (Chen et al. 2021): the lane
    change's keys without the highway's road and spawn grid, plus the merging-lane cost."""
    config = {key: value for key, value in default_config().items() if key not in HIGHWAY_KEYS}
    config.update(
        {
            "spawn_speed_range": [25.0, 27.0],  # [m/s]
            "comfort": False,  # the merging paper's reward has no comfort term
            # weight of the merging-lane cost -exp(-(x - merge end)² / (10 × merging lane length))
            "merging_lane_weight": 4.0,
            "supervisor_priority": "merging",  # see SUPERVISOR_PRIORITIES
            "supervisor_version": 4,
        }
    )
    return config


def scenario_default_config(scenario: str) -> dict[str, Any]:
    """The default config of a scenario (:data:`LANE_CHANGE` or :data:`MERGE`)."""
    return merge_default_config() if scenario == MERGE else default_config()


Check = Callable[[Any], bool]


def _number(lo: float | None = None, hi: float | None = None, strict_lo: bool = False) -> tuple[Check, str]:
    def check(v: Any) -> bool:
        if not is_number(v):
            return False
        if lo is not None and (v <= lo if strict_lo else v < lo):
            return False
        return hi is None or v <= hi

    bound = "" if lo is None else (f" > {lo}" if strict_lo else f" >= {lo}")
    bound += "" if hi is None else f" and <= {hi}"
    return check, f"a finite number{bound}"


def _integer(lo: int, hi: int | None = None) -> tuple[Check, str]:
    def check(v: Any) -> bool:
        return is_integer(v) and lo <= int(v) and (hi is None or int(v) <= hi)

    return check, f"an integer >= {lo}" + ("" if hi is None else f" and <= {hi}")


def _pair(lo: float, integer: bool = False, hi: float | None = None) -> tuple[Check, str]:
    def check(v: Any) -> bool:
        if not isinstance(v, (list, tuple)) or len(v) != 2:
            return False
        if not all(is_integer(x) if integer else is_number(x) for x in v):
            return False
        return lo <= v[0] <= v[1] and (hi is None or v[1] <= hi)

    kind = "integers" if integer else "numbers"
    return check, f"a pair [min, max] of finite {kind} with {lo} <= min <= max" + ("" if hi is None else f" <= {hi}")


def _boolean() -> tuple[Check, str]:
    return (lambda v: isinstance(v, bool)), "a boolean: true or false (True or False in a key:value on the command line)"


def _speeds() -> tuple[Check, str]:
    def check(v: Any) -> bool:
        if not isinstance(v, (list, tuple)) or len(v) < 2:
            return False
        if not all(is_number(x) and x >= 0 for x in v):
            return False
        steps = [b - a for a, b in itertools.pairwise(v)]
        return all(s > 0 for s in steps) and max(steps) - min(steps) < 1e-6

    return check, "an increasing, evenly spaced list of >= 2 speeds >= 0 (highway-env's MDPVehicle assumes even spacing)"


def _any() -> tuple[Check, str]:
    return (lambda v: True), "anything"


_POSITIVE = _number(0, strict_lo=True)
MAX_VEHICLES = 10_000  # the most AVs, HDVs or spawn slots of a lane a road may hold
_NON_NEGATIVE = _number(0)

_SCHEMA: dict[str, tuple[Check, str]] = {
    "density": ((lambda v: is_integer(v) and v in DENSITIES), f"one of {sorted(DENSITIES)}"),
    "n_avs": _integer(1, MAX_VEHICLES),  # range against the density is checked below
    "hdv_count_range": _pair(0, integer=True, hi=MAX_VEHICLES),
    "road_length": _number(0, 1e6, strict_lo=True),  # [m]
    "lanes_count": _integer(1, 64),
    "lane_width": _POSITIVE,
    "speed_limit": _POSITIVE,
    "spawn_start": _NON_NEGATIVE,
    "spawn_spacing": _POSITIVE,
    "spawn_position_noise": _NON_NEGATIVE,
    "spawn_slots_per_lane": _integer(1, MAX_VEHICLES),
    "spawn_speed_range": _pair(0),
    "simulation_frequency": _integer(1, 1000),  # [Hz]
    "policy_frequency": _integer(1, 100),  # [Hz]
    "duration": _number(0, 86_400, strict_lo=True),  # [s]
    "target_speeds": _speeds(),
    "hdv_politeness": _number(0, 1),
    "hdv_style": ((lambda v: v in HDV_STYLES), f"one of {sorted(HDV_STYLES)}"),
    "hdv_b_safe": _POSITIVE,
    "hdv_lane_change_threshold": _NON_NEGATIVE,
    "obs_vehicles_count": _integer(1, 100),
    "obs_x_range": _POSITIVE,
    "obs_y_range": _POSITIVE,
    "obs_speed_range": _POSITIVE,
    "safety_weight": _NON_NEGATIVE,
    "headway_weight": _NON_NEGATIVE,
    "speed_weight": _NON_NEGATIVE,
    "comfort_weight": _NON_NEGATIVE,
    "comfort": _boolean(),
    "obs_target_speed": _boolean(),
    "headway_time": _POSITIVE,
    "headway_max_distance": _POSITIVE,
    "reward_speed_range": _pair(0),
    "harsh_acceleration_threshold": _POSITIVE,
    "rule_acceleration_threshold": _POSITIVE,
    "merging_lane_weight": _NON_NEGATIVE,
    "supervisor_priority": ((lambda v: v in SUPERVISOR_PRIORITIES), f"one of {list(SUPERVISOR_PRIORITIES)}"),
    "safety_supervisor": _boolean(),
    "supervisor_horizon": _number(0, 60, strict_lo=True),
    "supervisor_min_gap": _number(0, 100),
    "supervisor_repeat_actions": _boolean(),
    "supervisor_rear_avs": _boolean(),
    "supervisor_version": ((lambda v: v in SUPERVISOR_VERSIONS), f"one of {list(SUPERVISOR_VERSIONS)}"),
    "supervisor_emergency_brake": ((lambda v: v is None or isinstance(v, bool)), "null, true or false"),
    "supervisor_joint_search": ((lambda v: v is None or isinstance(v, bool)), "null, true or false"),
    "supervisor_mobil_safety": _boolean(),
    "supervisor_shadow": _boolean(),
    "screen_width": _integer(1, 10_000),
    "screen_height": _integer(1, 10_000),
    "centering_position": _any(),
    "scaling": _POSITIVE,
    "show_trajectories": _boolean(),
    "render_agent": _boolean(),
    "offscreen_rendering": ((lambda v: v is None or isinstance(v, bool)), "null, true or false"),
    "manual_control": _boolean(),
    "real_time_rendering": _boolean(),
}


def _fail(key: str, value: Any, allowed: str) -> ValueError:
    return ValueError(f"Invalid config['{key}'] = {value!r}: expected {allowed}.")


def _keys(scenario: str) -> list[str]:
    if scenario == MERGE:
        return [key for key in _SCHEMA if key not in HIGHWAY_KEYS]
    return [key for key in _SCHEMA if key not in MERGE_KEYS]


def validate_config(config: dict[str, Any], scenario: str = LANE_CHANGE) -> None:
    """Check a merged config; raise one ``ValueError`` naming the key, the value and what is allowed.

    :param config: a full scenario config (defaults merged with overrides)
    :param scenario: :data:`LANE_CHANGE` or :data:`MERGE`
    :raises ValueError: on an unknown key, a wrong type, a value out of range, or inconsistent keys
    """
    keys = _keys(scenario)
    unknown = sorted(set(config) - set(keys), key=repr)  # a key may be any value
    if unknown:
        raise ValueError(f"Unknown config key(s) {unknown} for the {scenario} scenario: allowed keys are {sorted(keys)}.")
    for key in keys:
        check, allowed = _SCHEMA[key]
        value = config[key]
        if key in ("n_avs", "hdv_count_range") and value is None:
            continue
        if not check(value):
            raise _fail(key, value, allowed)

    avs_lo, avs_hi = SCENARIO_DENSITIES[scenario][config["density"]]["avs"]  # a mix of one's own: with hdv_count_range
    if config["n_avs"] is not None and config["hdv_count_range"] is None and not avs_lo <= config["n_avs"] <= avs_hi:
        allowed = f"an integer in [{avs_lo}, {avs_hi}], the AV range of density {config['density']} (any with hdv_count_range)"
        raise _fail("n_avs", config["n_avs"], allowed)
    frames = config["simulation_frequency"] / config["policy_frequency"]
    if frames != int(frames):
        allowed = f"a multiple of policy_frequency = {config['policy_frequency']}"
        raise _fail("simulation_frequency", config["simulation_frequency"], allowed)
    lo, hi = config["reward_speed_range"]
    if lo == hi:
        raise _fail("reward_speed_range", config["reward_speed_range"], "a pair with min < max")
    if scenario == MERGE:
        if config["supervisor_version"] not in MERGE_SUPERVISOR_VERSIONS:
            allowed = f"one of {list(MERGE_SUPERVISOR_VERSIONS)} on the merge (its version 3 released the emergency brake "
            raise _fail("supervisor_version", config["supervisor_version"], allowed + "differently; that code is not kept)")
        _check_merge_spawn(config)
    else:
        _check_highway(config)


def _check_highway(config: dict[str, Any]) -> None:
    road_width = (config["lanes_count"] - 1) * config["lane_width"]
    if road_width > config["obs_y_range"]:
        most_lanes = int(config["obs_y_range"] // config["lane_width"]) + 1
        raise _fail(
            "lanes_count",
            config["lanes_count"],
            f"at most {most_lanes} lanes: the observation normalises y by obs_y_range = {config['obs_y_range']} m "
            f"and clips it, so lanes more than {config['obs_y_range']} m from lane 0 would look the same "
            "(raise obs_y_range with lanes_count)",
        )
    slots = config["lanes_count"] * config["spawn_slots_per_lane"]
    n_avs = resolved_n_avs(config)
    most_hdvs = resolved_hdv_range(config)[1]
    if n_avs + most_hdvs > slots:
        raise _fail(
            "spawn_slots_per_lane",
            config["spawn_slots_per_lane"],
            f"enough slots for {n_avs} AVs + {most_hdvs} HDVs on {config['lanes_count']} lanes "
            f"(at least {-(-(n_avs + most_hdvs) // config['lanes_count'])} per lane)",
        )
    if config["spawn_spacing"] < 5.0 + 2 * config["spawn_position_noise"] + 1e-9:
        limit = f"at most (spawn_spacing - 5 m vehicle length) / 2 = {(config['spawn_spacing'] - 5.0) / 2} m"
        raise _fail("spawn_position_noise", config["spawn_position_noise"], limit + " so that spawned vehicles never overlap")


def _check_merge_spawn(config: dict[str, Any]) -> None:
    from sb3_marl.sim.merge_road import RAMP_SPAWN, SPAWN_SPACING

    n_avs, most = resolved_n_avs(config, MERGE), resolved_hdv_range(config, MERGE)[1]
    if -(-n_avs // 2) + -(-most // 2) > len(RAMP_SPAWN):  # half the vehicles (rounded up) start on the ramp
        raise _fail(
            "hdv_count_range",
            config["hdv_count_range"],
            f"a range whose maximum fits the ramp's {len(RAMP_SPAWN)} spawn points with {n_avs} AVs "
            f"(at most {2 * (len(RAMP_SPAWN) - -(-n_avs // 2))} HDVs)",
        )
    if 5.0 + 2 * config["spawn_position_noise"] + 1e-9 > SPAWN_SPACING:
        limit = f"at most (the {SPAWN_SPACING} m spawn spacing - 5 m vehicle length) / 2 = {(SPAWN_SPACING - 5.0) / 2} m"
        raise _fail("spawn_position_noise", config["spawn_position_noise"], limit + " so that spawned vehicles never overlap")


def resolved_n_avs(config: dict[str, Any], scenario: str = LANE_CHANGE) -> int:
    """Number of AVs of an instance: ``n_avs`` or, when unset, the density's maximum."""
    if config["n_avs"] is not None:
        return int(config["n_avs"])
    return SCENARIO_DENSITIES[scenario][config["density"]]["avs"][1]


def resolved_hdv_range(config: dict[str, Any], scenario: str = LANE_CHANGE) -> tuple[int, int]:
    """Inclusive range of HDV counts sampled at each reset."""
    if config["hdv_count_range"] is not None:
        lo, hi = config["hdv_count_range"]
        return int(lo), int(hi)
    return SCENARIO_DENSITIES[scenario][config["density"]]["hdvs"]


def supervisor_version(overrides: dict[str, Any] | None, scenario: str = LANE_CHANGE) -> int:
    """The supervisor version a config of ``overrides`` (over the scenario's defaults) runs."""
    return int({**scenario_default_config(scenario), **(overrides or {})}["supervisor_version"])


#: Every evaluation's two protocols -> ``safety_supervisor``: the authors' (on), the policy alone (off).
SUPERVISOR_PROTOCOLS: dict[str, bool] = {"on": True, "off": False}


def with_supervisor(config: dict | None, supervisor: bool | str) -> dict:
    """A copy of ``config`` with the safety supervisor on or off (a bool or a key of
    :data:`SUPERVISOR_PROTOCOLS`): the setting's one writer once a config is made, for each
    evaluation protocol and the per-episode dropout of training (:class:`wrappers.copies.CopyRunner`)."""
    on = SUPERVISOR_PROTOCOLS[supervisor] if isinstance(supervisor, str) else bool(supervisor)
    return {**(config or {}), "safety_supervisor": on}
