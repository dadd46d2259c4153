"""A climb planned by the DARPA-tasks paper's method (``strategy: search``) without any motion
primitive, executed in-process on G1: from the 4-contact stance on rung 1 (hands on rung 5), the
free-flyer guide path, the best-first contact search (it chose every hold) and generic
contact-body paths for every transition (the primitive directory points at an empty one), then
the QP controller in lock-step with a one-period actuation latency, to both feet on rung 2."""
from __future__ import annotations

import pytest

from climb_checks import assert_standing_on, check_run

pytestmark = [pytest.mark.sim, pytest.mark.heavy]


def test_a_searched_rung_without_primitives_is_executed_to_both_feet_on_rung_2(tmp_path, monkeypatch):
    import dataclasses

    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings
    from planner_node import climb_planner

    library_loads = []  # what the adaptation found in the primitive directory: no library at all
    real_load = climb_planner.load_library

    def recorded_load(*args, **kwargs):
        try:
            library = real_load(*args, **kwargs)
        except Exception as exc:
            library_loads.append(f"{type(exc).__name__}: {exc}")
            raise
        library_loads.append(f"{len(library.primitives)} primitives")
        return library

    monkeypatch.setattr(climb_planner, "load_library", recorded_load)

    settings = load_climb_settings()
    empty = tmp_path / "no_primitives"
    empty.mkdir()
    settings = dataclasses.replace(settings, planner_overrides={**settings.planner_overrides,
                                                                "planning.primitives_dir": str(empty)})
    result = run_climb(ClimbRequest(ladder="default", robot="g1", rungs=2, mode="qp", out_dir=tmp_path, seed=0,
                                    strategy="search", start_posture="ladder_4_contacts", command_delay_ticks=1),
                       settings)
    try:
        s = result.summary
        feet, loads = check_run(result, settings, "qp")
        assert s["success"], s["failure_reason"]
        assert set(s["plan_stages_s"]) == {"guide_path", "contact_search", "adaptation"}
        # no primitive could be used: the adaptation found no library (every transition generic)
        assert library_loads and all(x.startswith("SpecError: primitives") for x in library_loads), library_loads
        assert feet == {"left_foot": 2, "right_foot": 2}, feet
        for foot in ("left_foot", "right_foot"):
            assert_standing_on(result.backend, foot, 2)
        # the search moved each limb once, one rung up: hands 5 -> 6, feet 1 -> 2
        assert s["grasps"] == {"left_hand": "rung_6", "right_hand": "rung_6"}
        moved = [t.moving_limb for t in result.plan.transitions if t.moving_limb]
        assert sorted(moved) == ["left_foot", "left_hand", "right_foot", "right_hand"]
        # every placement was found from the F/T sensors, and the feet carry the robot at the end
        assert len(result.controller.events_of("contact_detected")) == len(moved)
        weight = 9.81 * result.backend.robot.mass
        feet_up = sum(loads[f].force_in_world[2] for f in ("left_foot", "right_foot"))
        assert loads["left_foot"].surface == loads["right_foot"].surface == "rung_2"
        assert feet_up > 0.5 * weight, (feet_up, weight)
        # the base rose by about one rung spacing (0.30 m along the 75-degree stringers: ~0.29 m up)
        base = result.log.arrays()["base"][:, 2]
        assert 0.2 < base[-1] - base[0] < 0.4
    finally:
        result.close()
