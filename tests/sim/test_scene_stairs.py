"""stairs_handrail (issues 17 and 18): three steps and a landing, climbed by G1 with a hand on the
handrail, planned by the DARPA-tasks paper's method and executed in-process.

The free-flyer guide path, the best-first contact search and the generic contact-body paths plan
the whole scene (tests/data/stairs_handrail_plan.json: ``scripts/plan.py --scenario
stairs_handrail --strategy search --out ...``): the feet walk up the first two steps, the right
hand grasps the handrail, the right foot goes up to the third step with the hand on the rail, the
hand lets go and grasps the rail further up, the left foot follows, the hand lets go for good
(the arm folded to its reference posture) and the feet walk onto the landing. The controller
executes every transition in lock-step with PyBullet, and the test checks what the simulator
measured. Two things this scene needed: the bridge latches a grasp on a scene's bilateral surface
(it took ladder rungs and rails only: the hand closed on the rail without latching and the robot
fell at the first weight shift), and the freed hand keeps clear of the rail it left."""
from __future__ import annotations

import pathlib

import numpy as np
import pytest

from climb_checks import check_run, execute_stored_scene_plan, touched_surfaces

pytestmark = [pytest.mark.sim, pytest.mark.heavy]

STORED_PLAN = pathlib.Path(__file__).resolve().parents[1] / "data" / "stairs_handrail_plan.json"
STEP_TOPS = {"step_1": 0.15, "step_2": 0.30, "step_3": 0.45, "landing": 0.60}  # [m] scene file


def test_a_bilateral_scene_surface_is_graspable_and_a_step_is_not():
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from sim_bridge.grasp import graspable

    scene = build_environment(load_scenario("stairs_handrail")).surfaces
    assert graspable(scene["handrail_left"]) and graspable(scene["handrail_right"])
    assert not graspable(scene["step_1"]) and not graspable(scene["landing"]) and not graspable(scene["ground"])
    ladder = build_environment(load_scenario("default")).surfaces
    assert graspable(ladder["rung_3"]) and not graspable(ladder["stringer_left"])


def test_the_stored_plan_of_the_stairs_is_executed_to_the_landing_with_a_hand_on_the_rail(tmp_path):
    from msgs_py.bag import read_bag

    result, settings = execute_stored_scene_plan("stairs_handrail", STORED_PLAN, tmp_path, 25)
    try:
        s = result.summary
        assert s["success"], s["failure_reason"]
        assert s["goal_reached"] and s["goal_distance_m"] <= 0.15, s
        assert s["settle_base_speed_max_m_s"] < 0.02
        assert s["scene"] == "stairs_handrail"
        assert {"ground", "step_1", "step_2", "step_3", "landing", "handrail_right"} <= set(s["contacts_used"])
        feet, loads = check_run(result, settings, "qp")
        moves = [(t.primitive, t.moving_limb) for t in result.plan.transitions]
        assert ("place_hand", "right_hand") in moves and moves[-1][0] != "place_hand"
        assert ("free_hand", "right_hand") in moves
        c = result.controller
        # the hand closed on the rail at each placement, and the grasp latched in the simulator
        # (no grasp_failed: a close that does not latch leaves the hand touching only)
        closes = [e for e in c.events_of("gripper") if e.values["command"] == "close"]
        n_hand = sum(1 for m in moves if m == ("place_hand", "right_hand"))
        assert len(closes) == n_hand >= 2, (closes, moves)
        # the right foot went up to step 3 while the hand held the rail: in the plan, and in the
        # bag the wrist's F/T read the rail's pull while that foot was in the air, above what the
        # hand's own weight reads while it travels to the rail (measured: 16 N against 8 N)
        transitions = result.plan.transitions
        held = [k for k, t in enumerate(transitions) if t.moving_limb == "right_foot"
                and t.stance.hold("right_hand") is not None]
        assert held and transitions[held[0]].target_stance.hold("right_foot").env_surface == "step_3", moves
        travel = moves.index(("place_hand", "right_hand"))
        wrist, index = [], []
        for m in read_bag(s["bag"], topics=["ft/right_wrist", "/ft/right_wrist", "controller/state",
                                            "/controller/state"]):
            msg = m.decode()
            if m.topic.strip("/") == "controller/state":
                index.append((m.stamp_ns, msg.transition_index))
            else:
                f = msg.wrench.force
                wrist.append((m.stamp_ns, float(np.linalg.norm([f.x, f.y, f.z]))))

        def wrist_median(k: int) -> float:  # [N] over the ticks of transition k (0-based)
            ticks = [t for t, i in index if i == k]
            values = [v for t, v in wrist if ticks[0] <= t <= ticks[-1]]
            assert len(values) > 20, (k, len(values))
            return float(np.median(values))

        assert wrist_median(held[0]) > wrist_median(travel) + 4.0, (wrist_median(held[0]), wrist_median(travel))
        # at the end: both feet on the landing, the hand off the rail, nothing but feet loaded
        assert loads["left_foot"].surface == loads["right_foot"].surface == "landing", loads
        weight = 9.81 * result.backend.robot.mass
        assert loads["left_foot"].normal_force + loads["right_foot"].normal_force > 0.9 * weight, loads
        assert set(loads) == {"left_foot", "right_foot"}, loads
        for foot in ("left_foot", "right_foot"):
            sole = result.backend.surface_pose(foot)[:3, 3]
            assert abs(sole[2] - STEP_TOPS["landing"]) < 0.02 and 1.4 < sole[0] < 2.4, (foot, sole)
        # nothing but the hands and the feet touched the scene
        touched = touched_surfaces(result.backend)
        assert touched <= set(STEP_TOPS) | {"ground"}, touched
        # the base went up the stairs: 0.60 m higher, about 1.9 m forward
        base = result.log.arrays()["base"]
        assert np.all(np.isfinite(base))
        assert base[-1, 2] - base[0, 2] > 0.5 and base[-1, 0] - base[0, 0] > 1.6, (base[0, :3], base[-1, :3])
    finally:
        result.close()
