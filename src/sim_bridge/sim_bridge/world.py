"""What the bridge builds from names: the scenario / environment and the initial posture.

Postures: an explicit Pinocchio configuration wins; ``standing`` (or ``reference``) is the robot's
reference posture on flat ground at the scenario's start pose (``start.pose`` of a scene, else the
origin); any other name is looked up in the shared stance
fixtures (climb_core.fixtures), whose hands holding a rung or rail are latched at t = 0.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from climb_core.contact import HANDS
from climb_core.errors import SpecError

STANDING = ("standing", "reference")


def resolve_scenario(source: Any, perturbed: bool):
    """(Scenario, Environment) from a name / path / YAML text / dict / Scenario; the environment is
    built with the spec's perturbation block when ``perturbed``."""
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario

    if source is None or (isinstance(source, str) and not source.strip()):
        raise SpecError("ladder", "a ladder spec (name, path, YAML text or mapping) is required")
    scenario = load_scenario(source)
    return scenario, build_environment(scenario, perturbed=perturbed and not scenario.perturbation.is_empty)


def initial_configuration(robot, env, q: np.ndarray | None, posture: str) -> tuple[np.ndarray, tuple[str, ...]]:
    """(q0 (nq,), hands to latch at t = 0)."""
    if q is not None and len(q):
        q = np.asarray(q, dtype=float)
        if q.shape != (robot.nq,) or not np.all(np.isfinite(q)):
            raise SpecError("q", f"must be {robot.nq} finite numbers (Pinocchio configuration of "
                                 f"{robot.config.name}), got shape {q.shape}")
        q = q.copy()
        q[3:7] /= np.linalg.norm(q[3:7])
        return q, ()
    if posture in STANDING:  # on the ground at the scenario's start pose (the origin for ladders)
        return env.place_at_start(robot.q_reference()), ()
    return _fixture_configuration(robot, env, posture)


def _fixture_configuration(robot, env, posture: str) -> tuple[np.ndarray, tuple[str, ...]]:
    try:
        from climb_core import fixtures
    except ImportError:
        raise SpecError("initial_posture", f"unknown posture {posture!r}: only 'standing' is available "
                                           "without climb_core.fixtures") from None
    stance_q = getattr(fixtures, "stance_configuration", None)
    if stance_q is None:
        raise SpecError("initial_posture", "climb_core.fixtures has no stance_configuration()")
    from climb_core.environment import build_environment

    nominal = build_environment(env.scenario, perturbed=False) if getattr(env, "perturbed", False) else env
    result = stance_q(posture, robot=robot, env=nominal)  # the plan's belief: the nominal ladder
    q, stance = (result if isinstance(result, tuple) else (result, None))
    hands: tuple[str, ...] = ()
    if stance is not None:
        hands = tuple(h.limb for h in stance.holds if h.limb in HANDS)
    return np.asarray(q, dtype=float).copy(), hands
