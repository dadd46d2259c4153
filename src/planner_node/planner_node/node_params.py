"""Parameters of the three planning nodes (ROS-free schemas; config/nodes/<node>.yaml holds the
same defaults, ROS params layout).

- ``guide_path`` (:class:`GuidePathParams`) and ``contact_search`` (:class:`ContactSearchParams`):
  the strategy, the primitive library and the stage's own knobs. They plan with the planner
  settings of the climb (:func:`stage_settings`: config/planner.yaml + config/climb.yaml's
  ``climb.planner_overrides``, the library replaced by theirs).
- ``primitive_adaptation`` (:class:`AdaptationParams`): every planner setting (the groups of
  :class:`~planner_node.settings.PlannerSettings`: planning.*, pcik.*, ...) plus the strategy and
  the ladder of a contact plan that carries no plan request. Its defaults are the climb's planner
  settings (:func:`adaptation_defaults`), so that the graph plans what the in-process climb plans.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from climb_core.params import param

from .pipeline import STRATEGIES
from .settings import PlannerSettings, climb_settings

GUIDE_PATH_NODE = "guide_path"
CONTACT_SEARCH_NODE = "contact_search"
ADAPTATION_NODE = "primitive_adaptation"

_STRATEGY_DOC = ("planning strategy when the request names none: primitives (the ladder paper: motion "
                 "primitives adapted by a multi-step search) | search (the DARPA-tasks paper: free-flyer guide "
                 "path and best-first contact search, ladders and scenes)")


@dataclass(frozen=True)
class GuidePathParams:
    strategy: str = param("primitives", unit="-", choices=STRATEGIES, description=_STRATEGY_DOC)
    library: str = param("forward", unit="-", description=(
        "primitive library config/primitives/<robot>/<library>/ (the adaptation's planning.strategy)"))
    primitives_dir: str = param("config/primitives", unit="-", description=(
        "primitive libraries (relative to the project root)"))
    projection_iterations: int = param(30, unit="-", min=1, max=200, description=(
        "Gauss-Newton iterations projecting a milestone onto its seed holds"))


@dataclass(frozen=True)
class ContactSearchParams:
    strategy: str = param("primitives", unit="-", choices=STRATEGIES, description=_STRATEGY_DOC)
    library: str = param("forward", unit="-", description=(
        "primitive library config/primitives/<robot>/<library>/ (the adaptation's planning.strategy)"))
    primitives_dir: str = param("config/primitives", unit="-", description=(
        "primitive libraries (relative to the project root)"))
    restarts: int = param(3, unit="-", min=0, max=50, description=(
        "Algorithm 1: perturbed restarts projecting a guide milestone onto its stance"))
    require_feasible: bool = param(False, unit="-", description=(
        "fail the stage when a seed stance has no feasible configuration (false: list it in the status, the "
        "adaptation samples other holds around it)"))


@dataclass(frozen=True)
class AdaptationParams(PlannerSettings):
    strategy: str = param("primitives", unit="-", choices=STRATEGIES, description=_STRATEGY_DOC)
    ladder: str = param("default", unit="-", description=(
        "ladder of a contact plan without a plan request and of primitive_adaptation/request (name in "
        "config/ladders/)"))


def stage_settings(library: str = "forward", primitives_dir: str = "config/primitives") -> PlannerSettings:
    """The climb's planner settings with this primitive library."""
    s = climb_settings()
    return dataclasses.replace(s, planning=dataclasses.replace(s.planning, strategy=library,
                                                               primitives_dir=primitives_dir))


def adaptation_defaults() -> AdaptationParams:
    """The primitive_adaptation node's defaults: the climb's planner settings (config/planner.yaml
    with config/climb.yaml's climb.planner_overrides) and the node's own fields' defaults."""
    s = climb_settings()
    return AdaptationParams(**{f.name: getattr(s, f.name) for f in dataclasses.fields(PlannerSettings)})


def planner_settings(params: AdaptationParams) -> PlannerSettings:
    """The planner groups of the adaptation node's parameters as a plain PlannerSettings."""
    return PlannerSettings(**{f.name: getattr(params, f.name) for f in dataclasses.fields(PlannerSettings)})


DEFAULTS = {GUIDE_PATH_NODE: GuidePathParams, CONTACT_SEARCH_NODE: ContactSearchParams}


def node_defaults(node_name: str):
    """The code's defaults of a planning node (what config/nodes/<node>.yaml must say)."""
    if node_name == ADAPTATION_NODE:
        return adaptation_defaults()
    return DEFAULTS[node_name]()
