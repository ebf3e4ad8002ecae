"""highway-env's collision test on the state array, compiled: the spherical pre-check and the
separating-axis test with the displacement of the next frame (``RoadObject.handle_collisions``),
``impact`` and ``crashed`` as highway-env sets them. Units: m, rad, s."""

from __future__ import annotations

import numpy as np

from sb3_marl.sim.kernel import (
    COLLIDABLE,
    CRASHED,
    DIAGONAL,
    HAS_IMPACT,
    HEADING,
    IMPACT_X,
    IMPACT_Y,
    IS_OBSTACLE,
    LENGTH,
    OBSTACLE_DIAGONAL,
    OBSTACLE_LENGTH,
    OBSTACLE_WIDTH,
    PRESENT,
    SPEED,
    WIDTH,
    X,
    Y,
    argsort,
    cos,
    jit,
    sin,
)

#: Rows above which the collision test finds its pairs by a sweep along x (below, all pairs are cheaper).
SWEPT = 32


@jit
def _polygon(state: np.ndarray, k: int) -> np.ndarray:
    """``RoadObject.polygon``: (5, 2) corners [m], the first repeated."""
    c, s = cos(state[k, HEADING]), sin(state[k, HEADING])
    points = np.empty((5, 2))
    if state[k, IS_OBSTACLE]:
        half_l, half_w = OBSTACLE_LENGTH / 2, OBSTACLE_WIDTH / 2
    else:
        half_l, half_w = LENGTH / 2, WIDTH / 2
    for i, (px, py) in enumerate(((-half_l, -half_w), (-half_l, half_w), (half_l, half_w), (half_l, -half_w))):
        points[i, 0] = c * px + -s * py + state[k, X]
        points[i, 1] = s * px + c * py + state[k, Y]
    points[4] = points[0]
    return points


@jit
def _project(polygon: np.ndarray, ax: float, ay: float) -> tuple[float, float]:
    low, high = np.inf, -np.inf
    for p in range(polygon.shape[0]):
        projected = polygon[p, 0] * ax + polygon[p, 1] * ay
        low, high = min(low, projected), max(high, projected)
    return low, high


@jit
def _interval_distance(min_a: float, max_a: float, min_b: float, max_b: float) -> float:
    return min_b - max_a if min_a < min_b else min_a - max_b


@jit
def _half_size(state: np.ndarray, k: int) -> tuple[float, float]:
    """Half the length and half the width [m] of row k's rectangle."""
    if state[k, IS_OBSTACLE]:
        return OBSTACLE_LENGTH / 2, OBSTACLE_WIDTH / 2
    return LENGTH / 2, WIDTH / 2


@jit
def _apart_sideways(state: np.ndarray, i: int, j: int, dx: float, dy: float, dt: float) -> bool:
    """Whether rows i and j are apart along i's lateral axis (the normal of its long sides, one of
    the axes :func:`handle_collision` tests) by more than 1 µm, j's rectangle and the next frame's
    displacement included (two vehicles side by side on adjacent lanes): the full test would
    find them neither intersecting nor about to, and change nothing (the margin exceeds its
    rounding)."""
    cos_i, sin_i = cos(state[i, HEADING]), sin(state[i, HEADING])
    cos_j, sin_j = cos(state[j, HEADING]), sin(state[j, HEADING])
    nx, ny = -sin_i, cos_i
    _, width_i = _half_size(state, i)
    length_j, width_j = _half_size(state, j)
    extent_j = length_j * abs(cos_j * nx + sin_j * ny) + width_j * abs(-sin_j * nx + cos_j * ny)
    rel_x = (state[i, SPEED] * cos_i - state[j, SPEED] * cos_j) * dt
    rel_y = (state[i, SPEED] * sin_i - state[j, SPEED] * sin_j) * dt
    gap = abs(dx * nx + dy * ny) - width_i - extent_j - abs(rel_x * nx + rel_y * ny)
    return gap > 1e-6


@jit
def handle_collision(state: np.ndarray, i: int, j: int, dt: float) -> None:
    """``RoadObject.handle_collisions(i, j)``: crash flags and the impact of the next frame (an
    obstacle takes no impact: the vehicle takes all of it). Obstacles do not collide with each other."""
    if not (state[i, COLLIDABLE] and state[j, COLLIDABLE]) or (state[i, IS_OBSTACLE] and state[j, IS_OBSTACLE]):
        return
    dx, dy = state[j, X] - state[i, X], state[j, Y] - state[i, Y]
    diagonal_i = OBSTACLE_DIAGONAL if state[i, IS_OBSTACLE] else DIAGONAL
    diagonal_j = OBSTACLE_DIAGONAL if state[j, IS_OBSTACLE] else DIAGONAL
    if np.sqrt(dx * dx + dy * dy) > (diagonal_i + diagonal_j) / 2 + state[i, SPEED] * dt:
        return
    if _apart_sideways(state, i, j, dx, dy, dt):
        return
    a, b = _polygon(state, i), _polygon(state, j)
    # displacement_a - displacement_b, each velocity (speed × direction) × dt
    rel_x = state[i, SPEED] * cos(state[i, HEADING]) * dt - state[j, SPEED] * cos(state[j, HEADING]) * dt
    rel_y = state[i, SPEED] * sin(state[i, HEADING]) * dt - state[j, SPEED] * sin(state[j, HEADING]) * dt
    intersecting = will_intersect = True
    min_distance, axis_x, axis_y = np.inf, 0.0, 0.0
    done = False
    for polygon in (a, b):
        for p in range(4):
            nx, ny = -polygon[p + 1, 1] + polygon[p, 1], polygon[p + 1, 0] - polygon[p, 0]
            norm = np.sqrt(nx * nx + ny * ny)
            nx, ny = nx / norm, ny / norm
            min_a, max_a = _project(a, nx, ny)
            min_b, max_b = _project(b, nx, ny)
            if _interval_distance(min_a, max_a, min_b, max_b) > 0:
                intersecting = False
            velocity_projection = nx * rel_x + ny * rel_y
            if velocity_projection < 0:
                min_a += velocity_projection
            else:
                max_a += velocity_projection
            distance = _interval_distance(min_a, max_a, min_b, max_b)
            if distance > 0:
                will_intersect = False
            if not intersecting and not will_intersect:
                done = True
                break
            if abs(distance) < min_distance:
                min_distance = abs(distance)
                cx = (((a[0, 0] + a[1, 0]) + a[2, 0]) + a[3, 0]) / 4 - (((b[0, 0] + b[1, 0]) + b[2, 0]) + b[3, 0]) / 4
                cy = (((a[0, 1] + a[1, 1]) + a[2, 1]) + a[3, 1]) / 4 - (((b[0, 1] + b[1, 1]) + b[2, 1]) + b[3, 1]) / 4
                sign = 1.0 if cx * nx + cy * ny > 0 else -1.0
                axis_x, axis_y = sign * nx, sign * ny
        if done:
            break
    if will_intersect:
        tx, ty = min_distance * axis_x, min_distance * axis_y
        if state[j, IS_OBSTACLE]:
            state[i, IMPACT_X], state[i, IMPACT_Y], state[i, HAS_IMPACT] = tx, ty, 1.0
        elif state[i, IS_OBSTACLE]:
            state[j, IMPACT_X], state[j, IMPACT_Y], state[j, HAS_IMPACT] = tx, ty, 1.0
        else:
            state[i, IMPACT_X], state[i, IMPACT_Y], state[i, HAS_IMPACT] = tx / 2, ty / 2, 1.0
            state[j, IMPACT_X], state[j, IMPACT_Y], state[j, HAS_IMPACT] = -tx / 2, -ty / 2, 1.0
    if intersecting:
        state[i, CRASHED] = state[j, CRASHED] = 1.0


@jit
def handle_collisions(state: np.ndarray, dt: float) -> None:
    """:func:`handle_collision` of every pair of present rows (i < j, highway-env's order), without
    the call where the two centres are so far apart along x that its pre-check would return at
    once (1 m of margin over it for rounding): the same outcome. The pairs near enough are found by
    a sweep along x on roads of more than :data:`SWEPT` rows, so the cost grows with the vehicles,
    not with their pairs."""
    n = state.shape[0]
    reach = max(DIAGONAL, OBSTACLE_DIAGONAL) + 1.0  # [m]
    if n <= SWEPT:
        for i in range(n):
            if state[i, PRESENT]:
                bound, x_i = reach + abs(state[i, SPEED]) * dt, state[i, X]
                for j in range(i + 1, n):
                    if state[j, PRESENT] and not abs(state[j, X] - x_i) > bound:
                        handle_collision(state, i, j, dt)
        return
    present = np.flatnonzero(state[:, PRESENT] > 0)
    x = state[:, X]
    by_x = present[argsort(x[present])]
    widest = reach  # the largest bound [m]
    for a in range(present.size):
        widest = max(widest, reach + abs(state[present[a], SPEED]) * dt)
    pairs = np.empty(4 * n, dtype=np.int64)  # i * n + j of the pairs near enough, grown as needed
    found = 0
    for a in range(by_x.size):
        for b in range(a + 1, by_x.size):
            if x[by_x[b]] - x[by_x[a]] > widest:
                break
            i, j = min(by_x[a], by_x[b]), max(by_x[a], by_x[b])
            if not abs(state[j, X] - state[i, X]) > reach + abs(state[i, SPEED]) * dt:
                if found == pairs.size:
                    pairs = np.concatenate((pairs, np.empty(pairs.size, dtype=np.int64)))
                pairs[found] = i * n + j
                found += 1
    for pair in pairs[:found][argsort(pairs[:found])]:
        handle_collision(state, pair // n, pair % n, dt)
