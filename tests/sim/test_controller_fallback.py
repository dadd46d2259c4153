"""QP failure -> fallback hold, in PyBullet: a forced infeasible QP never sends garbage."""
from __future__ import annotations

import numpy as np
import pytest

from controller_node.params import load_controller_params
from controller_node.qp import DaqpSolver, QpFailure, load_metadata, load_problem
from controller_node.runner import InProcessRunner

pytestmark = pytest.mark.sim


def test_forced_infeasible_qp_falls_back_to_a_safe_hold(tmp_path):
    from sim_bridge.pybullet_backend import PyBulletBackend

    # 1 % of the effort limits cannot hold G1 up and the acceleration bounds forbid it to fall:
    # every QP is infeasible
    params = load_controller_params(**{"qp.torque_limit_fraction": 0.01, "qp.joint_acceleration_bound": 1.0,
                                       "qp.base_acceleration_bound": 1.0, "qp.failure_dir": str(tmp_path),
                                       "qp.max_saved_failures": 3})
    backend = PyBulletBackend()
    try:
        runner = InProcessRunner.start(backend, params, posture="standing")
        effort = backend.robot.effort_limits()
        z0 = runner.sim_state.base.q[2]
        com0 = runner.controller.wb.data.com[0].copy()
        outputs = []
        runner.on_tick.append(lambda s, o: outputs.append(o))
        log = runner.run(1.0)
    finally:
        backend.close()
    c = runner.controller
    assert c.fsm.state == "failure"
    assert all(o.status.qp_status == 1 and o.status.fallback for o in outputs)
    assert c.qp_failures >= len(outputs) == 200  # counted on every tick
    assert all(np.all(np.isfinite(o.values)) and np.all(np.abs(o.values) <= effort + 1e-9) for o in outputs)
    # the fallback (equality-only whole-body solve, saturated torques) keeps G1 standing for 1 s
    assert not log.fell, log.fall_reason
    assert runner.sim_state.base.q[2] > z0 - 0.03  # [m]
    assert np.linalg.norm(np.array(log.com)[-1][:2] - com0[:2]) < 0.03  # [m] CoM still over the feet
    # the failing problems were saved (bounded count) and replay as failures
    saved = sorted(tmp_path.glob("*.npz"))
    assert len(saved) == 3
    assert load_metadata(saved[0])["fsm_state"] in ("idle", "failure")
    with pytest.raises(QpFailure):
        DaqpSolver().solve(load_problem(saved[0]))
