"""Fuzzing every node of the graph through its interfaces (issue 20: "no bad message, parameter,
service call or signal may kill a node"), with the engine of scripts/fuzz_nodes.py and a small
budget (the script runs it longer): each subscription gets hypothesis-generated well-typed
messages (NaN, inf, huge, empty, wrong lengths, unknown names; random and mutations of a valid
message) and raw byte garbage, each service random requests. Every node must stay alive, answer
every call (a refusal carries its reason), report the garbage on ``diagnostics``, keep serving
good input afterwards (the bridge steps in lock-step with the live controller, the controller
takes a valid plan, a planning stage answers a request with its id, ...) and exit 0 on SIGINT.
The node table is fuzz_nodes.NODES (one entry per executable; a node whose entry point is not in
its setup.py yet is skipped)."""
from __future__ import annotations

import json
import sys

import pytest
from harness import ROOT

pytestmark = pytest.mark.ros

sys.path.insert(0, str(ROOT / "scripts"))
import fuzz_nodes  # noqa: E402

EXAMPLES = 6  # well-typed messages per topic, requests per service
GARBAGE = 2  # raw garbage messages per topic
BUDGET_S = 90.0  # [s] of fuzzing, spread over every input of every node


#: failures of other helpers' nodes at the time of writing (xfail, not strict: an XPASS says the
#: owner fixed it); the lead removes them once fixed
KNOWN_GAPS = {
    "climb_coordinator": "garbage on its subscriptions is neither reported on diagnostics nor answered "
                         "(owner: climb_coordinator)",
}


def _params(entries):
    return [pytest.param(e, id=e.executable, marks=[pytest.mark.xfail(reason=KNOWN_GAPS[e.executable], strict=False)]
                         if e.executable in KNOWN_GAPS else []) for e in entries]


@pytest.fixture(scope="module")
def figures():
    entries = fuzz_nodes.available()
    assert entries, "no node executable found"
    return fuzz_nodes.fuzz(entries, EXAMPLES, GARBAGE, seed=20, budget_s=BUDGET_S, log=print)


@pytest.mark.parametrize("entry", _params(fuzz_nodes.NODES))
def test_node_survives_fuzzing_and_keeps_serving(figures, entry):
    if fuzz_nodes.entry_point(entry) is None:
        pytest.skip(f"no `{entry.executable}` entry point in src/{entry.package}/setup.py yet")
    f = figures["nodes"][entry.executable]
    failures = "\n".join(f["failures"])
    assert f["alive"], failures
    assert f["serving"], failures
    assert not f["failures"], failures
    assert f["exit_code"] == 0, failures
    assert f["topics"] or f["services"], f"{entry.executable}: no interface found to fuzz"
    if f["topics"]:
        assert f["messages"] > 0 and f["garbage"] > 0, json.dumps(f)
        if entry.garbage_is_bad:
            assert f["reports"] > 0, f"{entry.executable} never reported the garbage on diagnostics"
