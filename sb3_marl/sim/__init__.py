"""The compiled road, knowing nothing of RL.

One array layout of the vehicles (:mod:`~sb3_marl.sim.kernel`), highway-env's equations compiled
on it (drivers: IDM, MOBIL and the rule driver; dynamics: the bicycle step and the frame loop;
collisions; lanes; meta-actions and their masks), the roads as data with their spawn
(:mod:`~sb3_marl.sim.road`: the lane change's highway; :mod:`~sb3_marl.sim.merge_road`: the
on-ramp merge) and the bridge to highway-env's own classes, the stock reference and renderer (:mod:`~sb3_marl.sim.simulator`).
"""

#: The two roads by name (each scenario is named after its road): the lane change's highway and
#: the on-ramp merge.
LANE_CHANGE, MERGE = "lane-change", "merge"
#: The HDVs' IDM car following by style (config ``hdv_style``): comfortable acceleration a and
#: deceleration b [m/s²], jam distance s0 [m] (front to front, a 5 m vehicle included) and time
#: headway T [s]. ``normal`` is highway-env's ``IDMVehicle``; ``timid`` and ``aggressive`` are ours.
HDV_STYLES = {
    "normal": (3.0, 5.0, 10.0, 1.5),
    "timid": (2.0, 4.0, 12.0, 2.0),
    "aggressive": (4.0, 6.0, 8.0, 1.0),
}
