"""The project's exceptions. Every user-facing error names the field and the rule it broke."""
from __future__ import annotations


class ClimbError(Exception):
    """Base class of every error the project raises on purpose."""


class SpecError(ClimbError, ValueError):
    """A malformed input (ladder spec, robot config, command, request).

    ``field`` is the dotted path of the offending field (``ladder.rung.diameter``), ``rule`` the
    rule it broke in plain words.
    """

    def __init__(self, field: str, rule: str):
        self.field = field
        self.rule = rule
        super().__init__(f"{field}: {rule}")


class InfeasibleError(ClimbError):
    """A configuration or stance that violates a physical constraint; ``constraint`` names it."""

    def __init__(self, constraint: str, detail: str = ""):
        self.constraint = constraint
        self.detail = detail
        super().__init__(f"{constraint}: {detail}" if detail else constraint)
