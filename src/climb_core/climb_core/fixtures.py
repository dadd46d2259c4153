"""Named stance fixtures: (Stance, q) pairs that tests, the bridge, the controller and the planner
share, computed with the contact IK and checked by the feasibility check.

Names (:data:`NAMES`):

- ``standing``: the robot's reference posture on flat ground at the origin, both soles on
  ``ground``.
- ``ladder_4_contacts``: in front of the ladder, both feet on rung ``feet_rung`` (arch of the
  foot centred on the rung, ``foot_spacing`` apart), both hands grasping rung ``hands_rung``
  (``hand_spacing`` apart); on ladders with flat treads, the hands hold the rails. When that
  posture is not feasible, nearby variants are tried (:func:`ladder_stance`).
- ``ladder_no_<limb>`` (``left_hand``, ``right_hand``, ``left_foot``, ``right_foot``): the
  same holds minus that limb, the freed limb moved off its rung (hand pulled back and down, foot
  lifted and pulled back; ``release_*``).

Every fixture is feasible (:func:`climb_core.feasibility.check`: holds within tolerance, joint
limits, no collision, forces in the cones, torques and grips within limits) or building it
raises :class:`~climb_core.errors.InfeasibleError`. Results are cached per process and on disk
under ``<project>/.cache/fixtures/`` keyed by a hash of the robot config and reference posture,
the scenario, the config/feasibility.yaml text and the source of the modules that build them.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import pathlib
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np
import pinocchio as pin

from . import feasibility, holds, ik
from .contact import FEET, HANDS, LIMBS, ContactPoint, Hold, Stance
from .errors import InfeasibleError, SpecError
from .geometry_cache import atomic_write
from .params import load_params, param

VERSION = 1
NODE_NAME = "fixtures"
NAMES = ("standing", "ladder_4_contacts") + tuple(f"ladder_no_{limb}" for limb in LIMBS)


@dataclass(frozen=True)
class FixtureParams:
    feet_rung: int = param(1, unit="-", min=1, description="rung under both feet (1 = lowest)")
    hands_rung: int = param(5, unit="-", min=1, description="rung both hands grasp")
    foot_spacing: float = param(0.24, unit="m", min=0.0, description=(
        "distance between the two feet along the rung"))
    hand_spacing: float = param(0.30, unit="m", min=0.0, description=(
        "distance between the two grasps along the rung"))
    foot_ball_offset: float = param(0.04, unit="m", description=(
        "second try: sole centre this far behind the rung (the ball of the foot on the rung)"))
    com_back_offsets: tuple[float, ...] = param((0.08, 0.14), unit="m", description=(
        "further tries: CoM target this far behind the feet (toward the robot)"))
    rail_hand_height: float = param(0.95, unit="m", min=0.0, description=(
        "treads (no graspable rung): hands on the rails this high above the feet's tread top"))
    seed_base_behind_feet: float = param(0.18, unit="m", description=(
        "IK seed: pelvis this far behind the feet's rung (toward the robot)"))
    seed_shoulder_pitch: float = param(-1.2, unit="rad", description="IK seed: both shoulder pitch joints")
    seed_elbow: float = param(0.6, unit="rad", description="IK seed: both elbow joints")
    release_hand_back: float = param(0.12, unit="m", min=0.0, description=(
        "a freed hand moves this far toward the robot"))
    release_hand_down: float = param(0.0, unit="m", min=0.0, description="a freed hand moves this far down")
    release_foot_lift: float = param(0.06, unit="m", min=0.0, description="a freed foot moves this far up")
    release_foot_back: float = param(0.08, unit="m", min=0.0, description=(
        "a freed foot moves this far toward the robot"))
    com_shift_step: float = param(0.02, unit="m", min=0.0, description=(
        "when a three-limb fixture is infeasible, the CoM target moves by this toward the "
        "remaining support, up to com_shift_steps times"))
    com_shift_steps: int = param(5, unit="-", min=0, description="number of CoM shifts tried")
    disk_cache: bool = param(True, unit="-", description="cache the fixtures under .cache/fixtures/")


def default_config_path() -> pathlib.Path:
    from .ros_env import project_root

    return project_root() / "config" / "feasibility.yaml"


def load_fixture_params(path: str | pathlib.Path | None = None) -> FixtureParams:
    return load_params(str(path or default_config_path()), FixtureParams, NODE_NAME)


@dataclass
class StanceFixture:
    name: str
    robot: str
    scenario: str
    stance: Stance
    q: np.ndarray  # (nq,) Pinocchio configuration
    result: feasibility.FeasibilityResult | None  # None when loaded from the disk cache
    key: str  # cache key

    def __iter__(self) -> Iterator[Any]:
        """Unpacks as (stance, q)."""
        return iter((self.stance, self.q.copy()))


_MEMORY: dict[tuple[str, str], StanceFixture] = {}
_KEYS: dict[tuple[str, int, int], tuple[Any, Any, str]] = {}


# --------------------------------------------------------------------------------------------
# public API


def fixture(name: str, robot: Any = "g1", env: Any = "default") -> StanceFixture:
    """The named fixture for a robot (RobotModel or config name) and an environment
    (Environment, Scenario, or scenario name / path / YAML text / dict)."""
    if name not in NAMES:
        raise SpecError("fixture", f"unknown fixture {name!r}; known: {', '.join(NAMES)}")
    robot = _robot(robot)
    env = _environment(env)
    memo = _KEYS.get((name, id(robot), id(env)))
    if memo is not None and memo[0] is robot and memo[1] is env:
        key = memo[2]
    else:
        key = _cache_key(name, robot, env)
        _KEYS[(name, id(robot), id(env))] = (robot, env, key)
    hit = _MEMORY.get((name, key))
    if hit is not None:
        return hit
    params = load_fixture_params()
    fx = _load_disk(name, key, robot, env) if params.disk_cache else None
    if fx is None:
        fx = _build(name, robot, env, params, key)
        if params.disk_cache:
            _save_disk(fx)
    _MEMORY[(name, key)] = fx
    return fx


def get(name: str, robot: Any = "g1", env: Any = "default") -> tuple[Stance, np.ndarray]:
    """(Stance, q) of the named fixture."""
    fx = fixture(name, robot, env)
    return fx.stance, fx.q.copy()


def stance_configuration(name: str, robot: Any = "g1", env: Any = "default") -> tuple[np.ndarray, Stance]:
    """(q, Stance) of the named fixture (the order sim_bridge.world expects)."""
    fx = fixture(name, robot, env)
    return fx.q.copy(), fx.stance


# --------------------------------------------------------------------------------------------
# building


def _robot(robot: Any) -> Any:
    if isinstance(robot, (str, pathlib.Path)):
        from .robot import load_robot

        return load_robot(robot)
    return robot


_ENVIRONMENTS: dict[str, Any] = {}


def _environment(env: Any) -> Any:
    if hasattr(env, "surfaces"):
        return env
    from .environment import build_environment
    from .ladder import load_scenario

    if isinstance(env, (str, pathlib.Path)):
        if str(env) not in _ENVIRONMENTS:
            _ENVIRONMENTS[str(env)] = build_environment(load_scenario(env))
        return _ENVIRONMENTS[str(env)]
    return build_environment(env if hasattr(env, "ladder") else load_scenario(env))


def _set_joints(robot: Any, q: np.ndarray, values: dict[str, float]) -> None:
    for joint, value in values.items():
        if joint in robot.joint_names:
            q[robot.model.joints[robot.model.getJointId(joint)].idx_q] = value


def _build(name: str, robot: Any, env: Any, params: FixtureParams, key: str) -> StanceFixture:
    cfg = feasibility.load_config()
    if name == "standing":
        q = robot.q_reference()
        stance = Stance(tuple(holds.hold_from_configuration(robot, env, q, limb, "ground", params=cfg.holds)
                              for limb in FEET), name="standing")
        return _checked(name, robot, env, stance, q, cfg, key)
    if name == "ladder_4_contacts":
        stance4, q4 = ladder_stance(robot, env, params, cfg, check=True)
        return _checked(name, robot, env, stance4, q4, cfg, key)
    four = fixture("ladder_4_contacts", robot, env)  # the three-limb stances start from it
    stance4, q4 = four.stance, four.q.copy()
    limb = name.removeprefix("ladder_no_")
    return _three_limb(name, limb, robot, env, stance4, q4, params, cfg, key)


def ladder_stance(robot: Any, env: Any, params: FixtureParams | None = None,
                  cfg: feasibility.FeasibilityConfig | None = None, *, check: bool = False
                  ) -> tuple[Stance, np.ndarray]:
    """(Stance, q) of the 4-contact ladder stance: feet on rung ``feet_rung``, hands on rung
    ``hands_rung`` (or, when that rung is a flat tread, on the hand rails at ``rail_hand_height``
    above the feet).

    check False: the first candidate the IK reaches, not checked for feasibility (e.g. to report
    why a robot cannot hold it). check True: candidates (hand rung / rail height +-1 step, ball
    of the foot on the rung, CoM pulled back) are tried in order until one passes
    :func:`climb_core.feasibility.check`. InfeasibleError when none does.
    """
    params = params or load_fixture_params()
    cfg = cfg or feasibility.load_config()
    if params.feet_rung > env.n_rungs:
        raise SpecError("fixtures.feet_rung", f"the ladder has {env.n_rungs} rungs, the fixture needs "
                                              f"rung {params.feet_rung}")
    feet_surface = f"rung_{params.feet_rung}"
    side = {"left_foot": 0.5, "right_foot": -0.5, "left_hand": 0.5, "right_hand": -0.5}
    forward = holds.ladder_forward(env)
    last = "IK did not reach the holds"
    for hand_spec in _hand_candidates(robot, env, params):
        for foot_offset in (0.0, params.foot_ball_offset):
            hold_params = dataclasses.replace(cfg.holds, foot_on_rung_offset=foot_offset)
            hs = [holds.make_hold(robot, env, limb, feet_surface, side[limb] * params.foot_spacing,
                                  params=hold_params) for limb in FEET]
            hs += [hand_spec(limb, hold_params) for limb in HANDS]
            stance = Stance(tuple(hs), name="ladder_4_contacts")
            feet_centre = 0.5 * (hs[0].centre + hs[1].centre)
            q0 = _ladder_seed(robot, params, feet_centre, forward)
            for com_back in (None,) + tuple(params.com_back_offsets):
                com = None if com_back is None else feet_centre[:2] - com_back * forward[:2]
                res = ik.solve(robot, env, q0, stance, com_target=com, hold_params=hold_params)
                if not res.success:
                    last = f"IK residual {res.residual:.4f} m"
                    continue
                if not check:
                    return stance, res.q
                fr = feasibility.check(robot, env, res.q, stance, cfg)
                if fr.feasible:
                    return stance, res.q
                last = fr.summary()
            if not check:
                break
    raise InfeasibleError("contact" if last.startswith("IK") else "equilibrium",
                          f"no ladder_4_contacts stance for {robot.config.name} on {env.name}: {last}")


def _ladder_seed(robot: Any, params: FixtureParams, feet_centre: np.ndarray, forward: np.ndarray) -> np.ndarray:
    q0 = robot.q_reference()
    q0[:2] = feet_centre[:2] - params.seed_base_behind_feet * forward[:2]
    q0[2] += feet_centre[2]
    yaw = float(np.arctan2(forward[1], forward[0]))
    q0[3:7] = pin.Quaternion(pin.utils.rpyToMatrix(0.0, 0.0, yaw)).coeffs()
    _set_joints(robot, q0, {f"{s}_shoulder_pitch_joint": params.seed_shoulder_pitch for s in ("left", "right")})
    _set_joints(robot, q0, {f"{s}_elbow_joint": params.seed_elbow for s in ("left", "right")})
    return q0


def _hand_candidates(robot: Any, env: Any, params: FixtureParams) -> list[Any]:
    """Functions (limb, hold params) -> Hold for the hands, preferred first."""
    side = {"left_hand": 0.5, "right_hand": -0.5}
    out = []
    rails = env.rails() if hasattr(env, "rails") else {}
    preferred = f"rung_{params.hands_rung}"
    def graspable(name: str) -> bool:  # both hands close around it (a round rung, a rect bar that fits)
        return all(holds.grasp_fits(robot, hand, env.surfaces[name]) for hand in side)

    if params.hands_rung <= env.n_rungs and graspable(preferred):
        for k in (params.hands_rung, params.hands_rung - 1, params.hands_rung + 1):
            if params.feet_rung < k <= env.n_rungs and graspable(f"rung_{k}"):
                out.append(lambda limb, hp, k=k: holds.make_hold(
                    robot, env, limb, f"rung_{k}", side[limb] * params.hand_spacing, params=hp))
    elif {"left", "right"} <= set(rails):
        feet_top = env.rung(params.feet_rung).top_z
        for dh in (0.0, -0.1, 0.1):
            height = feet_top + params.rail_hand_height + dh
            out.append(lambda limb, hp, height=height: _rail_hold(robot, limb, env, rails, height, hp))
    if not out:
        raise SpecError("fixtures.hands_rung", f"the hands of {robot.config.name} cannot close around "
                                               f"rung_{params.hands_rung} of {env.name} (not a cylinder nor a "
                                               "rect bar that fits the hand) and there are no hand rails on both "
                                               "sides")
    return out


def _rail_hold(robot: Any, limb: str, env: Any, rails: dict, height: float, hold_params: holds.HoldParams) -> Hold:
    rail = rails["left" if limb == "left_hand" else "right"]
    T = np.asarray(rail.T_world_surface)
    a = T[:3, 0]
    if abs(a[2]) < 1e-6:
        s = 0.0
    else:
        s = float(np.clip((height - T[2, 3]) / a[2], -0.5 * rail.length + 0.05, 0.5 * rail.length - 0.05))
    return holds.make_hold(robot, env, limb, rail.name, s, params=hold_params)


def _release_offsets(limb: str, params: FixtureParams) -> list[tuple[float, float]]:
    """(toward the robot [m], up [m]) moves of a freed limb, preferred first."""
    if limb in HANDS:
        b, d = params.release_hand_back, params.release_hand_down
        return [(b, -d), (1.5 * b, -d), (b, -d - 0.05), (0.5 * b, -d - 0.1), (b, 0.05)]
    b, h = params.release_foot_back, params.release_foot_lift
    return [(b, h), (0.5 * b, h), (0.25 * b, 1.5 * h), (1.5 * b, h), (0.0, 2.0 * h)]


def _three_limb(name: str, limb: str, robot: Any, env: Any, stance4: Stance, q4: np.ndarray,
                params: FixtureParams, cfg: feasibility.FeasibilityConfig, key: str) -> StanceFixture:
    stance = dataclasses.replace(stance4.without(limb), name=name)
    forward = holds.ladder_forward(env)
    targets: dict[str, Any] = {}
    for hold in stance.holds:  # keep the other limbs exactly where they are
        rs = robot.config.limbs[hold.limb].surface
        T = robot.T_world_surface(hold.limb, q4)
        free = holds.grasp_axis_in_surface(rs) if hold.bilateral else None
        targets[hold.limb] = holds.HoldTarget(hold.limb, rs.frame, T, holds.frame_pose_from_surface(robot, hold.limb, T),
                                              free, "grasp" if hold.bilateral else "pose")
    support = np.mean([h.centre for h in stance.holds], axis=0)
    com0 = pin.centerOfMass(robot.model, robot.model.createData(), q4)
    T_now = robot.T_world_surface(limb, q4)
    last = None
    for back, up in _release_offsets(limb, params):
        T_free = T_now.copy()
        T_free[:3, 3] += -back * forward + np.array([0.0, 0.0, up])
        targets[limb] = T_free
        for k in range(params.com_shift_steps + 1):
            com_target = None
            if k > 0:
                d = support[:2] - com0[:2]
                d_lat = d - forward[:2] * float(forward[:2] @ d)  # shift sideways only
                n = float(np.linalg.norm(d_lat))
                if n < 1e-9:
                    break
                com_target = com0[:2] + min(k * params.com_shift_step, n) * d_lat / n
            res = ik.solve(robot, env, q4, targets, com_target=com_target, hold_params=cfg.holds)
            if not res.success:
                continue
            fr = feasibility.check(robot, env, res.q, stance, cfg)
            last = fr
            if fr.feasible:
                return StanceFixture(name, robot.config.name, env.name, stance, res.q, fr, key)
            if fr.violated == ["collision"]:
                break  # a CoM shift will not clear it: next release move
    detail = last.summary() if last is not None else "IK failed"
    raise InfeasibleError(last.violated[0] if last is not None and last.violated else "contact",
                          f"fixture {name}: {detail}")


def _checked(name: str, robot: Any, env: Any, stance: Stance, q: np.ndarray, cfg: feasibility.FeasibilityConfig,
             key: str) -> StanceFixture:
    fr = feasibility.check(robot, env, q, stance, cfg)
    if not fr.feasible:
        raise InfeasibleError(fr.violated[0], f"fixture {name} for {robot.config.name}: {fr.summary()}")
    return StanceFixture(name, robot.config.name, env.name, stance, q, fr, key)


# --------------------------------------------------------------------------------------------
# disk cache


def _cache_key(name: str, robot: Any, env: Any) -> str:
    from .ros_env import project_root

    h = hashlib.sha256()
    h.update(f"v{VERSION}:{name}".encode())
    cfg_path = getattr(robot.config, "config_path", None)
    if cfg_path is not None and pathlib.Path(cfg_path).is_file():
        h.update(pathlib.Path(cfg_path).read_bytes())
    h.update(repr(robot.config.name).encode())
    h.update(np.asarray(robot.q_reference()).tobytes())
    h.update(repr(env.scenario).encode())
    h.update(repr(getattr(env, "perturbed", False)).encode())
    feas = project_root() / "config" / "feasibility.yaml"
    if feas.is_file():
        h.update(feas.read_bytes())
    here = pathlib.Path(__file__).resolve().parent
    for module in ("fixtures.py", "holds.py", "ik.py", "feasibility.py", "collision.py"):  # the code that built it
        h.update((here / module).read_bytes())
    return h.hexdigest()[:20]


def _cache_dir() -> pathlib.Path:
    from .ros_env import project_root

    return project_root() / ".cache" / "fixtures"


def _hold_to_json(h: Hold) -> dict:
    return {"limb": h.limb, "robot_surface": h.robot_surface, "env_surface": h.env_surface,
            "friction": h.friction, "bilateral": h.bilateral, "grip_force_limit": h.grip_force_limit,
            "points": [[p.position.tolist(), p.normal.tolist()] for p in h.points]}


def _hold_from_json(d: dict) -> Hold:
    return Hold(limb=d["limb"], robot_surface=d["robot_surface"], env_surface=d["env_surface"],
                points=tuple(ContactPoint(np.array(p), np.array(n)) for p, n in d["points"]),
                friction=float(d["friction"]), bilateral=bool(d["bilateral"]),
                grip_force_limit=float(d["grip_force_limit"]))


def _save_disk(fx: StanceFixture) -> None:
    path = _cache_dir() / f"{fx.robot}-{fx.name}-{fx.key}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"version": VERSION, "name": fx.name, "robot": fx.robot, "scenario": fx.scenario,
           "stance": {"name": fx.stance.name, "holds": [_hold_to_json(h) for h in fx.stance.holds]},
           "q": fx.q.tolist()}
    try:  # a private temporary file per writer: processes building the same fixture at once
        atomic_write(path, json.dumps(doc))  # (the planning nodes of a graph) used to race on one
    except OSError:  # a cache that cannot be written costs time, never the request
        pass


def _load_disk(name: str, key: str, robot: Any, env: Any) -> StanceFixture | None:
    path = _cache_dir() / f"{robot.config.name}-{name}-{key}.json"
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
        stance = Stance(tuple(_hold_from_json(h) for h in doc["stance"]["holds"]), name=doc["stance"]["name"])
        q = np.array(doc["q"], dtype=float)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if q.shape != (robot.model.nq,):
        return None
    return StanceFixture(name, robot.config.name, env.name, stance, q, None, key)
