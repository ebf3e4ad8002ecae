"""highway-env's road, lane and vehicle classes with the scenario's hot routines made cheaper.

highway-env computes with numpy on scalars and 2-vectors (``np.clip`` of one float, ``np.dot`` of
two 2-vectors, ``np.array`` per velocity), which costs a few microseconds per call and dominates a
step of this scenario. The subclasses below redo those routines on Python floats, operation for
operation, so they return bit-identical numbers; every other behaviour is highway-env's own code.
Transcendental functions stay numpy's (``np.sin``, ``np.arcsin``, ``np.power``...), so the same
libm/SIMD routine rounds them. tests/envs/test_simulator.py checks that seeded random-action
episodes give identical trajectories with :data:`STOCK` and :data:`FAST`.

Where exactness needs a precondition it is checked: :class:`FastStraightLane` only accepts lanes
parallel to an axis (direction (±1, 0) or (0, ±1)), where every product in highway-env's
``np.dot`` is exact, so a BLAS dot with fused multiply-add rounds the same as Python.
:meth:`FastIDMVehicle.desired_gap` takes its fast path only for an ego heading of exactly 0 rad
for the same reason, and otherwise calls highway-env's.

:data:`COMPILED` (the scenario's default) goes one step further: :class:`CompiledRoad` runs the
frames of a whole policy step in compiled code (:mod:`sb3_marl.envs.kernel`) on an array copy of
the vehicles' state and writes the result back into the same objects. Its transcendental functions
are the C library's, which differ from numpy's SIMD ones in the last bit for some inputs, so it
agrees with :data:`STOCK` within a rounding tolerance, with identical episode outcomes
(tests/envs/test_kernel.py, benchmarks/kernel_parity.py).

Units: positions and distances in m, speeds in m/s, accelerations in m/s², angles in rad, time in s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from highway_env import utils
from highway_env.road.lane import StraightLane
from highway_env.road.road import LaneIndex, Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle, MDPVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import Landmark

from sb3_marl.envs import kernel

_HIGH_LEVEL_ACTIONS = frozenset(("FASTER", "SLOWER", "LANE_LEFT", "LANE_RIGHT"))


def clip(value: float, low: float = -1.0, high: float = 1.0) -> float:
    """``np.clip`` of one number: the same comparisons (max with ``low``, then min with ``high``)."""
    return min(max(value, low), high)


def _odd(function: np.ufunc) -> Callable[[float], float]:
    """``function`` (sin, tan, arcsin, arctan: odd, with f(±0) = ±0 exactly in IEEE 754 / C99
    Annex F) on one float, skipping numpy for the frequent ±0 input."""

    def call(value: float) -> float:
        return value if value == 0 else float(function(value))

    return call


sin, tan, arcsin, arctan = _odd(np.sin), _odd(np.tan), _odd(np.arcsin), _odd(np.arctan)


def cos(value: float) -> float:
    """``np.cos`` of one float; cos(±0) = 1 exactly."""
    return 1.0 if value == 0 else float(np.cos(value))


def xy(position: np.ndarray) -> tuple[float, float]:
    """A 2-D position (an array, as highway-env keeps it, or a sequence) as two Python floats (exact)."""
    try:
        x, y = position.tolist()
    except AttributeError:
        x, y = position
    return float(x), float(y)


class FastStraightLane(StraightLane):
    """``StraightLane`` for a lane parallel to the x or y axis, with float local coordinates."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        direction = self.direction.tolist()
        if sorted(abs(component) for component in direction) != [0.0, 1.0]:
            raise ValueError(
                f"FastStraightLane needs a lane parallel to an axis, got direction {direction}; "
                "use highway-env's StraightLane for other lanes."
            )
        self._start = self.start.astype(float).tolist()
        self._direction = direction
        self._lateral = self.direction_lateral.tolist()
        self._length = float(self.length)

    def local_coordinates(self, position: np.ndarray) -> tuple[float, float]:
        """(longitudinal, lateral) [m] of a world position."""
        return self.local_xy(*xy(position))

    def local_xy(self, x: float, y: float) -> tuple[float, float]:
        """(longitudinal, lateral) [m] of the world point (x, y); highway-env's ``np.dot`` sums
        from 0.0 in this order, and every product is exact on an axis-parallel lane."""
        dx, dy = x - self._start[0], y - self._start[1]
        (ux, uy), (lx, ly) = self._direction, self._lateral
        return (0.0 + dx * ux) + dy * uy, (0.0 + dx * lx) + dy * ly

    def on_lane(self, position, longitudinal=None, lateral=None, margin=0) -> bool:
        if longitudinal is None or lateral is None:
            longitudinal, lateral = self.local_coordinates(position)
        return (
            abs(lateral) <= self.width_at(longitudinal) / 2 + margin
            and -self.VEHICLE_LENGTH <= longitudinal < self._length + self.VEHICLE_LENGTH
        )

    def is_reachable_from(self, position: np.ndarray) -> bool:
        if self.forbidden:
            return False
        longitudinal, lateral = self.local_coordinates(position)
        return abs(lateral) <= 2 * self.width_at(longitudinal) and 0 <= longitudinal < self._length + self.VEHICLE_LENGTH

    def distance_with_heading(self, position: np.ndarray, heading: float | None, heading_weight: float = 1.0):
        if heading is None:
            return self.distance(position)
        return self.distance_with_heading_xy(*xy(position), heading, heading_weight)

    def distance_with_heading_xy(self, x: float, y: float, heading: float, heading_weight: float = 1.0) -> float:
        """``distance_with_heading`` of the world point (x, y) [m] and a heading [rad]."""
        s, r = self.local_xy(x, y)
        angle = abs(utils.wrap_to_pi(heading - self.heading))  # local_angle: the lane heading is constant
        return abs(r) + max(s - self._length, 0) + max(0 - s, 0) + heading_weight * angle


class FastRoadNetwork(RoadNetwork):
    """``RoadNetwork`` whose closest-lane search keeps the first minimum without numpy."""

    _indexed: list[tuple[LaneIndex, StraightLane, bool]] | None = None  # (index, lane, fast), graph order

    def add_lane(self, _from: str, _to: str, lane: StraightLane) -> None:
        super().add_lane(_from, _to, lane)
        self._indexed = None

    def get_closest_lane_index(self, position: np.ndarray, heading: float | None = None) -> LaneIndex:
        if self._indexed is None:
            self._indexed = [
                ((_from, _to, _id), lane, isinstance(lane, FastStraightLane))
                for _from, to_dict in self.graph.items()
                for _to, lanes in to_dict.items()
                for _id, lane in enumerate(lanes)
            ]
        x, y = xy(position)
        closest, closest_distance = None, None
        for index, lane, fast in self._indexed:
            if heading is not None and fast:
                distance = lane.distance_with_heading_xy(x, y, heading)
            else:
                distance = lane.distance_with_heading(position, heading)
            if closest is None or distance < closest_distance:  # np.argmin: the first minimum
                closest, closest_distance = index, distance
        return closest


class FastRoad(Road):
    """``Road`` with a float neighbour search and pre-filtered pairwise collision tests.

    ``Road.step`` calls ``handle_collisions(vehicles[i], vehicles[j])`` on every pair i < j. That
    routine does nothing unless (1) the centres are within the "spherical" reach
    ``(diagonal_i + diagonal_j) / 2 + speed_i * dt`` and (2) highway-env's separating-axis test
    finds the rectangles intersecting now or after the displacement ``velocity * dt``. Here a pair
    is skipped only when (1) fails by more than ``SLACK`` m, or when the rectangles are separated
    by more than ``SLACK`` m on one of vehicle i's two axes (which the separating-axis test also
    checks) even after the whole relative displacement. The other pairs reach highway-env's exact
    routine in the stock order.
    """

    SLACK = 1e-6  # [m], far above the rounding error of positions of a few hundred m
    #: lane index -> occupants, valid during :meth:`act` only (None outside it)
    _occupants: dict[LaneIndex, list[tuple[float, Vehicle]]] | None = None

    def step(self, dt: float) -> None:
        """Step every vehicle's dynamics by ``dt`` s, then resolve collisions in ``Road.step``'s order."""
        vehicles = self.vehicles
        for vehicle in vehicles:
            vehicle.step(dt)
        candidates = self._candidate_pairs(dt)
        for i, vehicle in enumerate(vehicles):
            for j in candidates.get(i, ()):
                vehicle.handle_collisions(vehicles[j], dt)
            for other in self.objects:
                vehicle.handle_collisions(other, dt)

    def _candidate_pairs(self, dt: float) -> dict[int, list[int]]:
        """For each vehicle i, the vehicles j > i (ascending) that may collide with it within ``dt`` s."""
        vehicles = self.vehicles
        if len(vehicles) < 2:
            return {}
        states = [(*xy(v.position), v.heading, v.speed, v.diagonal, v.LENGTH / 2, v.WIDTH / 2) for v in vehicles]
        max_reach = max(state[4] for state in states) + max(state[3] for state in states) * dt + self.SLACK
        by_x = sorted(range(len(states)), key=lambda k: states[k][0])
        candidates: dict[int, list[int]] = {}
        for rank, a in enumerate(by_x):  # sweep along x: only vehicles within max_reach m can touch
            for b in by_x[rank + 1 :]:
                if states[b][0] - states[a][0] > max_reach:
                    break
                i, j = min(a, b), max(a, b)
                if self._may_collide(states[i], states[j], dt):
                    candidates.setdefault(i, []).append(j)
        for later in candidates.values():
            later.sort()
        return candidates

    @classmethod
    def _may_collide(cls, state_i: tuple, state_j: tuple, dt: float) -> bool:
        xi, yi, hi, si, di, half_li, half_wi = state_i
        xj, yj, hj, sj, dj, half_lj, half_wj = state_j
        dx, dy = xj - xi, yj - yi
        reach = (di + dj) / 2 + si * dt + cls.SLACK
        if dx * dx + dy * dy > reach * reach:
            return False
        cos_i, sin_i = cos(hi), sin(hi)
        cos_d, sin_d = abs(cos(hj - hi)), abs(sin(hj - hi))
        rel_x = (si * cos_i - sj * cos(hj)) * dt  # relative displacement of i w.r.t. j
        rel_y = (si * sin_i - sj * sin(hj)) * dt
        for (ax, ay), own_half, other_half in (
            ((cos_i, sin_i), half_li, half_lj * cos_d + half_wj * sin_d),
            ((-sin_i, cos_i), half_wi, half_lj * sin_d + half_wj * cos_d),
        ):
            gap = abs(ax * dx + ay * dy) - own_half - other_half - abs(ax * rel_x + ay * rel_y)
            if gap > cls.SLACK:
                return False
        return True

    def act(self) -> None:
        """Every vehicle decides its action; positions stay fixed meanwhile, so the lanes'
        occupants (see :meth:`neighbour_vehicles`) are computed once per lane for the whole phase."""
        self._occupants = {}
        try:
            super().act()
        finally:
            self._occupants = None

    def lane_occupants(self, lane_index: LaneIndex) -> list[tuple[float, Vehicle]]:
        """(longitudinal coordinate [m], vehicle) of the vehicles and objects on a lane, road order.

        "On the lane" is highway-env's ``on_lane`` with a 1 m margin, as in its neighbour search.
        """
        cache = self._occupants
        if cache is not None and lane_index in cache:
            return cache[lane_index]
        lane = self.network.get_lane(lane_index)
        occupants = []
        for v in self.vehicles + self.objects:
            if isinstance(v, Landmark):
                continue
            s_v, lat_v = lane.local_coordinates(v.position)
            if lane.on_lane(v.position, s_v, lat_v, margin=1):
                occupants.append((s_v + 0, v))  # highway-env adds the segment offset, 0 here
        if cache is not None:
            cache[lane_index] = occupants
        return occupants

    def neighbour_vehicles(self, vehicle: Vehicle, lane_index: LaneIndex = None) -> tuple[Vehicle | None, Vehicle | None]:
        """Preceding and following vehicle on ``lane_index`` (default: the vehicle's lane)."""
        if self.neighbour_vehicles_connected_lanes:
            return super().neighbour_vehicles(vehicle, lane_index)
        lane_index = lane_index or vehicle.lane_index
        if not lane_index:
            return None, None
        s = self.network.get_lane(lane_index).local_coordinates(vehicle.position)[0]
        s_front = s_rear = None
        v_front = v_rear = None
        for s_v, v in self.lane_occupants(lane_index):
            if v is vehicle:
                continue
            if s <= s_v and (s_front is None or s_v <= s_front):
                s_front, v_front = s_v, v
            if s_v < s and (s_rear is None or s_v > s_rear):
                s_rear, v_rear = s_v, v
        return v_front, v_rear


class FastControlledVehicle(ControlledVehicle):
    """``ControlledVehicle`` with float kinematics, steering control and low-level act."""

    def act(self, action: dict | str | None = None) -> None:
        if action in _HIGH_LEVEL_ACTIONS or isinstance(action, dict):
            super().act(action)
            return
        self.follow_road()
        steering = self.steering_control(self.target_lane_index)
        Vehicle.act(
            self,
            {
                "steering": clip(steering, -self.MAX_STEERING_ANGLE, self.MAX_STEERING_ANGLE),
                "acceleration": self.speed_control(self.target_speed),
            },
        )

    def steering_control(self, target_lane_index: LaneIndex) -> float:
        target_lane = self.road.network.get_lane(target_lane_index)
        longitudinal, lateral = target_lane.local_coordinates(self.position)
        lane_future_heading = target_lane.heading_at(longitudinal + self.speed * self.TAU_PURSUIT)
        lateral_speed_command = -self.KP_LATERAL * lateral
        heading_command = arcsin(clip(lateral_speed_command / utils.not_zero(self.speed), -1.0, 1.0))
        heading_ref = lane_future_heading + clip(heading_command, -np.pi / 4, np.pi / 4)
        heading_rate_command = self.KP_HEADING * utils.wrap_to_pi(heading_ref - self.heading)
        slip_angle = arcsin(clip(self.LENGTH / 2 / utils.not_zero(self.speed) * heading_rate_command, -1.0, 1.0))
        steering_angle = arctan(2 * tan(slip_angle))
        return float(clip(steering_angle, -self.MAX_STEERING_ANGLE, self.MAX_STEERING_ANGLE))

    def step(self, dt: float) -> None:
        """highway-env's kinematic bicycle step, on floats."""
        self.clip_actions()
        beta = arctan(1 / 2 * tan(self.action["steering"]))
        heading, speed = self.heading, self.speed  # type: ignore[has-type]
        x, y = xy(self.position)
        self.position[0] = x + speed * cos(heading + beta) * dt
        self.position[1] = y + speed * sin(heading + beta) * dt
        if self.impact is not None:  # type: ignore[has-type]
            self.position += self.impact  # type: ignore[has-type]
            self.crashed = True
            self.impact = None
        self.heading = heading + speed * sin(beta) / (self.LENGTH / 2) * dt
        self.speed = speed + self.action["acceleration"] * dt
        self.on_state_update()


class FastMDPVehicle(MDPVehicle, FastControlledVehicle):
    """highway-env's ``MDPVehicle`` (the AVs) on :class:`FastControlledVehicle`."""

    def speed_to_index(self, speed: float) -> int:
        """Index of the target speed nearest ``speed`` [m/s] on the uniform ladder: highway-env's
        formula on floats (``round`` rounds half to even, as ``np.round``)."""
        ladder = self.target_speeds
        top = ladder.size - 1
        low, high = float(ladder[0]), float(ladder[top])
        return min(max(round((speed - low) / (high - low) * top), 0), top)

    def decide(self, action: str) -> None:
        """The target speed [m/s] and target lane that ``act(action)`` sets for a meta-action,
        without its low-level control (``Road.act`` recomputes that in the same frame)."""
        if action in ("FASTER", "SLOWER"):
            index = self.speed_to_index(self.speed) + (1 if action == "FASTER" else -1)
            self.speed_index = int(np.clip(index, 0, self.target_speeds.size - 1))
            self.target_speed = self.index_to_speed(self.speed_index)
        elif action in ("LANE_LEFT", "LANE_RIGHT"):
            self.follow_road()
            _from, _to, _id = self.target_lane_index  # type: ignore[has-type]
            side = 1 if action == "LANE_RIGHT" else -1
            target = (_from, _to, np.clip(_id + side, 0, len(self.road.network.graph[_from][_to]) - 1))
            if self.road.network.get_lane(target).is_reachable_from(self.position):
                self.target_lane_index = target


class FastIDMVehicle(IDMVehicle, FastControlledVehicle):
    """highway-env's ``IDMVehicle`` (IDM + MOBIL, the HDVs) with float IDM routines."""

    def act(self, action: dict | str | None = None) -> None:
        if self.crashed:
            return
        self.follow_road()
        if self.enable_lane_change:
            self.change_lane_policy()
        steering = clip(self.steering_control(self.target_lane_index), -self.MAX_STEERING_ANGLE, self.MAX_STEERING_ANGLE)
        front_vehicle, rear_vehicle = self.road.neighbour_vehicles(self, self.lane_index)
        acceleration = self.acceleration(ego_vehicle=self, front_vehicle=front_vehicle, rear_vehicle=rear_vehicle)
        if self.lane_index != self.target_lane_index:
            front_vehicle, rear_vehicle = self.road.neighbour_vehicles(self, self.target_lane_index)
            target_acceleration = self.acceleration(ego_vehicle=self, front_vehicle=front_vehicle, rear_vehicle=rear_vehicle)
            acceleration = min(acceleration, target_acceleration)
        Vehicle.act(self, {"steering": steering, "acceleration": clip(acceleration, -self.ACC_MAX, self.ACC_MAX)})

    def acceleration(
        self, ego_vehicle: ControlledVehicle, front_vehicle: Vehicle = None, rear_vehicle: Vehicle = None
    ) -> float:
        """IDM acceleration [m/s²] of ``ego_vehicle`` behind ``front_vehicle``."""
        if not ego_vehicle or not isinstance(ego_vehicle, Vehicle):
            return 0
        ego_target_speed = getattr(ego_vehicle, "target_speed", 0)
        if ego_vehicle.lane and ego_vehicle.lane.speed_limit is not None:
            ego_target_speed = clip(ego_target_speed, 0, ego_vehicle.lane.speed_limit)
        ratio = max(ego_vehicle.speed, 0) / abs(utils.not_zero(ego_target_speed))
        acceleration = self.COMFORT_ACC_MAX * (1 - float(np.power(ratio, self.DELTA)))
        if front_vehicle:
            d = ego_vehicle.lane_distance_to(front_vehicle)
            acceleration -= self.COMFORT_ACC_MAX * float(
                np.power(self.desired_gap(ego_vehicle, front_vehicle) / utils.not_zero(d), 2)
            )
        return acceleration

    def desired_gap(self, ego_vehicle: Vehicle, front_vehicle: Vehicle = None, projected: bool = True) -> float:
        """IDM desired gap [m]; highway-env's routine unless the ego heading is exactly 0 rad."""
        if projected and ego_vehicle.heading != 0:
            return super().desired_gap(ego_vehicle, front_vehicle, projected)
        if projected:  # velocity difference along the ego direction (1, ±0): exact products
            ego_cos, ego_sin = cos(ego_vehicle.heading), sin(ego_vehicle.heading)
            front_cos, front_sin = cos(front_vehicle.heading), sin(front_vehicle.heading)
            dv_x = ego_vehicle.speed * ego_cos - front_vehicle.speed * front_cos
            dv_y = ego_vehicle.speed * ego_sin - front_vehicle.speed * front_sin
            dv = (0.0 + dv_x * ego_cos) + dv_y * ego_sin
        else:
            dv = ego_vehicle.speed - front_vehicle.speed
        ab = -self.COMFORT_ACC_MAX * self.COMFORT_ACC_MIN
        return self.DISTANCE_WANTED + ego_vehicle.speed * self.TIME_WANTED + ego_vehicle.speed * dv / (2 * float(np.sqrt(ab)))


class CompiledRoad(FastRoad):
    """``FastRoad`` that runs whole policy steps in compiled code (:mod:`sb3_marl.envs.kernel`).

    :meth:`simulate` copies the vehicles' state into an array, runs the frames, and writes the
    state back into the same vehicle objects, so everything else (observations, rendering,
    highway-env's own methods) reads them as usual. It needs the scenario's road: straight lanes
    along +x from x = 0, lane k centred at y = k × lane width, all of one length, width and speed
    limit, on one segment; :meth:`compiled_geometry` says whether this road is one.
    """

    _geometry: tuple[int, float, float, float] | bool | None = False  # False: not checked yet

    def compiled_geometry(self) -> tuple[int, float, float, float] | None:
        """(lanes, lane width [m], length [m], speed limit [m/s]) of the road, or None if the
        kernel cannot simulate it."""
        if self._geometry is False:
            self._geometry = None
            lanes = self.network.lanes_list()
            segments = [to for to_dict in self.network.graph.values() for to in to_dict]
            if len(segments) == 1 and all(isinstance(lane, FastStraightLane) for lane in lanes):
                width, length, limit = lanes[0].width, lanes[0]._length, lanes[0].speed_limit
                if limit is not None and all(
                    lane._start == [0.0, k * width]
                    and lane._direction == [1.0, 0.0]
                    and lane.width == width
                    and lane._length == length
                    and lane.speed_limit == limit
                    and not lane.forbidden
                    for k, lane in enumerate(lanes)
                ):
                    self._geometry = (len(lanes), float(width), float(length), float(limit))
        return self._geometry  # type: ignore[return-value]

    def capture(self) -> np.ndarray:
        """The road's state array (:func:`capture` of its vehicles)."""
        return capture(self.vehicles)

    def simulate(self, frames: int, dt: float, exit_x: float, state: np.ndarray | None = None) -> None:
        """``frames`` × (``act``, ``step(dt)``) in compiled code; vehicles whose centre passes
        ``exit_x`` m leave after the frame (HDVs are removed, AVs stop colliding).

        :param state: the :meth:`capture` of this step (the safety supervisor's), whose target
            lanes and speeds are refreshed from the vehicles (the AVs' meta-actions set them
            since); None: captured now
        """
        n_lanes, lane_width, length, speed_limit = self.compiled_geometry()  # type: ignore[misc]
        vehicles = self.vehicles  # type: ignore[has-type]
        if state is None:
            state = self.capture()
        else:
            state[:, kernel.TARGET_LANE] = [v.target_lane_index[2] for v in vehicles]
            state[:, kernel.TARGET_SPEED] = [v.target_speed for v in vehicles]
        kernel.simulate(state, frames, dt, n_lanes, lane_width, length, speed_limit, exit_x)
        lanes = self.network.lanes_list()
        kept = []
        for v, row in zip(vehicles, state.tolist()):
            v.position[0], v.position[1] = row[kernel.X], row[kernel.Y]
            v.heading, v.speed = row[kernel.HEADING], row[kernel.SPEED]
            lane = int(row[kernel.LANE])
            if lane != v.lane_index[2]:
                v.lane_index, v.lane = (*v.lane_index[:2], lane), lanes[lane]
            if row[kernel.IS_HDV]:
                v.timer = row[kernel.TIMER]
                target = int(row[kernel.TARGET_LANE])
                if target != v.target_lane_index[2]:
                    v.target_lane_index = (*v.target_lane_index[:2], target)
            v.crashed, v.collidable = bool(row[kernel.CRASHED]), bool(row[kernel.COLLIDABLE])
            v.impact = np.array([row[kernel.IMPACT_X], row[kernel.IMPACT_Y]]) if row[kernel.HAS_IMPACT] else None
            v.action["steering"], v.action["acceleration"] = row[kernel.STEERING], row[kernel.ACCELERATION]
            if row[kernel.PRESENT]:
                kept.append(v)
        self.vehicles = kept


def capture(vehicles: list[Vehicle]) -> np.ndarray:
    """The vehicles' state array, (n, :data:`~sb3_marl.envs.kernel.COLUMNS`): :func:`kernel_row` of each, in order."""
    return np.array([kernel_row(v) for v in vehicles], dtype=np.float64).reshape(-1, kernel.COLUMNS)


def kernel_row(v: Vehicle) -> tuple:
    """One vehicle's row of the kernel's state array (see the column names in :mod:`~sb3_marl.envs.kernel`)."""
    hdv = isinstance(v, IDMVehicle)
    impact = v.impact
    return (
        *xy(v.position),
        v.heading,
        v.speed,
        v.lane_index[2],
        v.target_lane_index[2],
        v.target_speed,
        hdv,
        v.timer if hdv else 0.0,
        v.crashed,
        v.collidable,
        True,
        *((0.0, 0.0) if impact is None else xy(impact)),
        impact is not None,
        v.action["steering"],
        v.action["acceleration"],
        *((v.POLITENESS, v.LANE_CHANGE_MAX_BRAKING_IMPOSED, v.LANE_CHANGE_MIN_ACC_GAIN) if hdv else (0.0, 0.0, 0.0)),
    )


@dataclass(frozen=True)
class Simulator:
    """The highway-env classes a scenario is built from."""

    road: type[Road]
    network: type[RoadNetwork]
    lane: type[StraightLane]
    av: type[MDPVehicle]
    hdv: type[IDMVehicle]


#: highway-env's own classes, the reference for parity tests.
STOCK = Simulator(road=Road, network=RoadNetwork, lane=StraightLane, av=MDPVehicle, hdv=IDMVehicle)
#: The same behaviour, cheaper.
FAST = Simulator(road=FastRoad, network=FastRoadNetwork, lane=FastStraightLane, av=FastMDPVehicle, hdv=FastIDMVehicle)
#: FAST with whole policy steps in compiled code (:class:`CompiledRoad`): equal to highway-env within
#: a per-step tolerance (see :mod:`sb3_marl.envs.kernel`).
COMPILED = Simulator(road=CompiledRoad, network=FastRoadNetwork, lane=FastStraightLane, av=FastMDPVehicle, hdv=FastIDMVehicle)
