"""The brace after an impact: what the controller changes while bracing and undoes after.

:class:`Brace` is the controller's record of one brace (fsm.BraceState drives it through the
controller's ``begin_brace`` / ``end_brace`` / ``brace_settled`` / ``lost_contacts`` /
``resume_after_brace``):

- at the start: the state it interrupted, every active contact's reference point in the world
  (from the measured joints and base: what "lost" is measured against), the posture task's
  stiffness and the grasps' force limits (both raised while bracing);
- at the end: those restored, and the impact monitor muted for ``impact.cooldown_s`` (the robot's
  own recovery motion must not read as a second blow).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Brace:
    since: float  # [s] sim time of the impact
    interrupted: str  # FSM state the impact interrupted
    anchors: dict[str, np.ndarray]  # limb -> contact reference point at the impact [m, world]
    posture_stiffness: float  # [1/s^2] restored at the end
    force_limits: dict[str, float] = field(default_factory=dict)  # grasp limb -> force limit [N] restored
    displacement: dict[str, float] = field(default_factory=dict)  # limb -> [m] at the check
    lost_holds: dict = field(default_factory=dict)  # limb -> the Hold it lost


def contact_point(oMf, contact) -> np.ndarray:
    """[m] world position of an active contact's reference point (its frame's placement now)."""
    M = oMf[contact.frame_id]
    return M.translation + M.rotation @ contact.reference_in_frame


__all__ = ["Brace", "contact_point"]
