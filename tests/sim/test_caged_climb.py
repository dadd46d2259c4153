"""The caged ladder (issue 18, "the caged ladder: 5 steps, with the smallest distance to the cage
asserted"), planned and executed in process.

config/ladders/caged.yaml: the vertical ladder's rungs (90 deg, round, every 25 cm, mu 0.25) with a
safety cage from 2.0 m up: three hoops 0.75 m deep behind the rungs and four vertical bars, static
boxes the robot climbs inside with its back to them. Its file sets what the vertical ladder's does:
the mount slowed near the heels and the feet pitched 10 deg toes up on the round rungs (level, the
5-step plan stopped on the left knee against rung 6 after 1200 s, and G1 fell at its first one-foot
stance on the vertical ladder; docs/planner.md).

Five rungs up, the robot's shoulders and head are inside the first two hoops. Judged on the
simulator: both feet on rung 5, both hands closed on the rung the plan ends on, nothing fell, no QP
failure, every contact inside its friction cone; and the least distance between the robot and the
cage over the whole run, from the recorded joint states and base pose (the bag) with the robot's
collision model: the robot never touched a cage bar (measured: 1.0 cm, the right shoulder against
the first hoop's side bar)."""
from __future__ import annotations

import numpy as np
import pytest

from climb_checks import climb_ladder_to

pytestmark = [pytest.mark.sim, pytest.mark.heavy, pytest.mark.long]  # make test-long (226-288 s)

RUNGS = 5
CAGE_CLEARANCE_M = 0.003  # [m] least robot-cage distance over the run (measured 0.0103)
EVERY = 10  # joint_states samples per distance query (the bag's 100 Hz -> 10 Hz)


def cage_distance(bag, robot, env) -> tuple[float, tuple[str, str]]:
    """Least distance [m] between the robot (collision model at the recorded states) and the
    scenario's obstacles, and the pair."""
    from climb_core import collision
    from msgs_py.bag import read_bag

    chk = collision.checker(robot, env)
    cage = [i for i, (_, b) in enumerate(chk.pair_names) if "obstacle" in b]
    assert len(cage) > 100
    column = {name: k for k, name in enumerate(robot.joint_names)}
    base, n, best = None, 0, (np.inf, ("", ""))
    for m in read_bag(bag, ["joint_states", "sim/base_truth"]):
        msg = m.decode()
        if m.topic == "sim/base_truth":
            p, o = msg.pose.pose.position, msg.pose.pose.orientation
            base = np.array([p.x, p.y, p.z, o.x, o.y, o.z, o.w])
            continue
        n += 1
        if base is None or n % EVERY:
            continue
        q = robot.q_reference().copy()
        q[:7] = base
        for name, value in zip(msg.name, msg.position):
            if name in column:
                q[7 + column[name]] = value
        d = chk.all_distances(q)[cage]
        k = int(np.argmin(d))
        if d[k] < best[0]:
            best = (float(d[k]), chk.pair_names[cage[k]])
    assert n > 5000  # the whole run was recorded and read
    return best


def test_the_caged_ladder_is_climbed_five_rungs_inside_its_cage_without_touching_it(tmp_path):
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot

    result, _ = climb_ladder_to("caged", RUNGS, tmp_path)
    try:
        distance, pair = cage_distance(result.summary["bag"], load_robot("g1"),
                                       build_environment(load_scenario("caged")))
        assert distance >= CAGE_CLEARANCE_M, (distance, pair)
    finally:
        result.close()
