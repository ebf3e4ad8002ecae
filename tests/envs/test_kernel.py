"""The compiled kernel against highway-env's classes: same episodes within a rounding tolerance.

COMPILED (the default: the kernel on the state array) is compared with STOCK (highway-env's own
classes stepping the same episodes frame by frame): the same seeded episodes and actions must give
the same events (crashes, lane changes, HDV lane decisions, lengths) and states within TOLERANCE.
benchmarks/kernel_parity.py runs the same comparison over hundreds of episodes per density.
"""

import numba
import numpy as np
import pytest
from helpers import make
from parity import compare, run_episode

from sb3_marl.envs import ENV_IDS
from sb3_marl.sim.collisions import SWEPT
from sb3_marl.sim.drivers import SCANNED, idm
from sb3_marl.sim.kernel import argsort
from sb3_marl.sim.lanes import heading_at, local_coordinates, on_lane_at, position
from sb3_marl.sim.simulator import COMPILED, STOCK

#: [m, rad, m/s, m/s²] largest state difference accepted: numpy's SIMD arcsin / arctan / tan /
#: power differ from the C library's in the last bit; measured up to ~1e-13 over 200 episodes.
TOLERANCE = 1e-9


#: The supervisor chooses the AVs' actions on both simulators alike; version 5's, because under
#: version 6 an episode at density 3 (seed 5) brakes an AV to a standstill, where the steering's
#: division by the speed turns last-bit differences into a different heading, and the IDM of the
#: vehicles behind it carries that past the tolerance (parity.compare sets only the stopped vehicles apart).
SUPERVISED = {"safety_supervisor": True, "supervisor_version": 5}


@pytest.mark.parametrize("density", [1, 2, 3])
@pytest.mark.parametrize(("policy", "config"), [("uniform", {}), ("cruise", {}), ("cruise", SUPERVISED)])
def test_compiled_kernel_matches_highway_env(density, policy, config):
    result = compare(STOCK, COMPILED, ENV_IDS[density], range(15), policy, **config)
    assert result.different_outcomes == []
    assert result.max_state_difference < TOLERANCE
    assert result.max_observation_difference < TOLERANCE
    if not config:
        assert result.crashes >= (10 if policy == "uniform" else 3)  # collisions and their impacts
    if policy == "cruise":
        assert result.hdv_lane_changes >= 2  # MOBIL lane changes and their aborts


@pytest.mark.parametrize(("policy", "supervisor"), [("uniform", False), ("cruise", True)])
def test_a_crowded_road_matches_highway_env(policy, supervisor):
    """90 vehicles on 3 lanes: past the sizes where the kernel searches a lane's neighbours by
    bisection (drivers.SCANNED) and finds the collision test's pairs by a sweep (collisions.SWEPT)."""
    lanes, vehicles = 3, 90
    slots = vehicles // lanes + 1
    config = {
        "n_avs": 6,
        "hdv_count_range": [vehicles - 6, vehicles - 6],
        "lanes_count": lanes,
        "spawn_slots_per_lane": slots,
        "road_length": 10.0 + slots * 40.0 + 200.0,
        "duration": 6,
        "safety_supervisor": supervisor,
    }
    assert vehicles // lanes > SCANNED and vehicles > SWEPT
    result = compare(STOCK, COMPILED, ENV_IDS[3], range(2), policy, **config)
    assert result.different_outcomes == []
    assert result.max_state_difference < TOLERANCE and result.max_observation_difference < TOLERANCE
    assert result.crashes >= 1 if policy == "uniform" else result.hdv_lane_changes >= 5


def test_compiled_kernel_is_the_default():
    env = make(3)
    env.reset(seed=0)
    assert env.simulator == COMPILED and not env._uses_objects()


def test_rendered_episodes_match_unrendered_ones():
    """With a viewer the frames run one by one (drawn in between), without it compiled: same episode."""
    plain = run_episode(COMPILED, ENV_IDS[2], seed=4, policy="cruise")
    env = make(2)
    env.render_mode = "rgb_array"
    env.reset(seed=4)
    env.render()  # creates the viewer: from now on frames run one by one
    rng = np.random.default_rng(4)
    for states in plain.states[1:]:
        env.step(rng.choice(5, env.n_avs, p=[0.04, 0.8, 0.04, 0.06, 0.06]))
        np.testing.assert_allclose(
            np.array([[*v.position, v.heading, v.speed] for v in env.road.vehicles]), states[:, :4], atol=TOLERANCE
        )


@pytest.mark.parametrize("style", ["timid", "aggressive"])
def test_the_hdv_styles_match_highway_env_given_their_parameters(style):
    """An HDV style's IDM parameters reach highway-env's vehicles as instance attributes: the
    compiled road and highway-env's classes still step the same episodes."""
    result = compare(STOCK, COMPILED, ENV_IDS[3], range(8), "cruise", hdv_style=style)
    assert result.different_outcomes == [] and result.max_state_difference < TOLERANCE


def test_the_normal_style_is_highway_envs_idm():
    from highway_env.vehicle.behavior import IDMVehicle

    from sb3_marl.sim import HDV_STYLES

    a, b, s0, t = HDV_STYLES["normal"]
    assert (a, -b, s0, t) == (
        IDMVehicle.COMFORT_ACC_MAX,
        IDMVehicle.COMFORT_ACC_MIN,
        IDMVehicle.DISTANCE_WANTED,
        IDMVehicle.TIME_WANTED,
    )


def test_the_kernels_argsort_is_numpys_stable_argsort():
    """On what the kernel sorts: floats with ties, ±0 and ±inf (distances, positions, priorities),
    and int64s with ties (collision pairs); empty and single arrays."""
    rng = np.random.default_rng(0)
    for size in [0, 1, 2, 5, 17, 40]:
        for _ in range(50):
            floats = rng.choice([-np.inf, -1.5, -0.0, 0.0, 0.25, 3.0, np.inf], size) + rng.integers(0, 2, size) * rng.random(
                size
            )
            ints = rng.integers(-3, 4, size)
            for values in (floats, ints):
                np.testing.assert_array_equal(argsort(values), np.argsort(values, kind="stable"))


#: Compiled functions run for every vehicle (and lane) at every frame, with their arguments on a road.
PER_VEHICLE = {
    "local_coordinates": (local_coordinates, lambda env: (env.horizon.lanes, 1, 80.0, 4.2)),
    "heading_at": (heading_at, lambda env: (env.horizon.lanes, 1, 80.0)),
    "position": (position, lambda env: (env.horizon.lanes, 1, 80.0, 0.3)),
    "on_lane_at": (on_lane_at, lambda env: (env.horizon.lanes, 1, 80.0, 0.3, 1.0)),
    "idm": (idm, lambda env: (env.state, env.horizon.lanes, 0, 1, 30.0)),
}


@pytest.mark.parametrize("name", sorted(PER_VEHICLE))
def test_the_per_vehicle_functions_update_no_reference_counts(name):
    """An array that a compiled function still reads inside a branch, or past a call that may
    raise, costs two atomic reference-count updates per call (see sb3_marl.sim.kernel.jit):
    compiled on their own, the machine code of these functions must hold none."""
    helper, arguments = PER_VEHICLE[name]
    env = make(1)
    env.reset(seed=0)
    helper(*arguments(env))  # the signature the kernel uses (e.g. a read-only lane table)
    # compiled afresh, as kernel.jit compiles (numba shows no machine code of cached functions)
    own = numba.njit(helper.py_func, error_model="numpy")
    signature = helper.signatures[0]
    own.compile(signature)
    body = own.inspect_asm(signature).split(".Lfunc_end0")[0]  # the function itself, not its Python wrapper
    assert "NRT_incref" not in body and "NRT_decref" not in body
