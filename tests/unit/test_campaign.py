"""climb_coordinator.campaign without the simulator: the cases' perturbation blocks are valid
scenarios, the journal resumes, the CSV and the figures (largest perturbation survived)."""
from __future__ import annotations

import csv

import pytest

from climb_coordinator import campaign
from climb_core.ladder import parse_scenario


def test_every_case_is_a_valid_scenario_the_simulator_alone_sees_perturbed():
    todo = campaign.cases(campaign.FAMILIES)
    assert len(todo) == 2 * 9 + 3 * 7 + 1 + 5 and len({c.id for c in todo}) == len(todo)
    for case in todo:
        scenario = parse_scenario(campaign.scenario_of(case), name=case.id)
        p = scenario.perturbation
        # sensor realism: F/T noise in every case (the ft_noise family's own level, the default elsewhere)
        assert case.ft_noise_percent() == (case.value if case.family == "ft_noise" else campaign.DEFAULT_FT_NOISE)
        assert case.ft_noise_percent() > 0.0
        if case.family == "ft_noise":
            assert case.unit == "%" and not p.drops and not p.rung_offsets
        if case.family == "rung_dz":
            assert p.rung_offset(2) == (0.0, pytest.approx(case.value))
        elif case.family.startswith("ball_"):
            (drop,) = p.drops
            assert drop.mass == case.value and drop.speed == 5.5 and drop.target_link == "torso"
            assert (drop.at_transition, drop.at_time) == campaign.PHASE_TRANSITIONS[case.family[5:]]
            assert drop.on_transition and drop.direction == pytest.approx(campaign.BALL_DIRECTION, abs=1e-3)
    with pytest.raises(ValueError, match="unknown family"):
        campaign.cases(["wind"])


def test_the_journal_resumes_and_the_outputs_say_what_was_survived(tmp_path):
    ran = []

    def fake(case):  # rung offsets up to 2 cm up and 3 cm down succeed; balls up to 7.5 kg
        ran.append(case.id)
        ok = (-0.03 - 1e-9 <= case.value <= 0.02 + 1e-9) if case.unit == "m" else case.value <= 7.5
        return {"case": case.id, "family": case.family, "value": case.value, "unit": case.unit, "success": ok,
                "fell": not ok, "failure_reason": "" if ok else "fell", "replans": 0, "replan_why": "",
                "qp_failures": 0, "rungs_reached": 2 if ok else 0, "sim_time_s": 100.0, "wall_time_s": 1.0,
                "max_cone_use": 0.8}

    journal = tmp_path / "journal.jsonl"
    todo = campaign.cases(["rung_dz", "ball_4_contacts"])
    rows = campaign.run_campaign(todo[:5], journal, workers=1, run=fake, say=lambda m: None)
    assert len(rows) == 5 and len(ran) == 5
    with open(journal, "a") as stream:
        stream.write('{"case": "rung_dz:0.0", "fam')  # a line cut by a kill
    rows = campaign.run_campaign(todo, journal, workers=1, run=fake, say=lambda m: None)
    assert len(rows) == len(todo) and len(ran) == len(todo)  # the 5 journaled cases were not rerun
    figures = campaign.write_outputs(rows, tmp_path / "out")
    assert figures["rung_dz_up_m"] == pytest.approx(0.02) and figures["rung_dz_down_m"] == pytest.approx(0.03)
    assert figures["ball_4_contacts_kg"] == 7.5
    with open(figures["csv"]) as stream:
        table = list(csv.DictReader(stream))
    assert len(table) == len(todo) and set(table[0]) == set(campaign.CSV_FIELDS)
    assert (tmp_path / "out" / "success.png").stat().st_size > 1000
    assert (tmp_path / "out" / "balls.png").stat().st_size > 1000  # the largest ball per phase
