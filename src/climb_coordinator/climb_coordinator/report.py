"""The run report from a bag alone (no ROS: rosbags decodes every message from the definitions the
bag embeds), and the trajectory comparison of ``replay.py --reexecute``.

    run = load_run("out/demo/bag")      # RunData: time series of the recorded topics
    paths = write_report(run, "out/demo/report")   # report.png, fsm_timeline.png, film_strip.png, report.md

What it reads (topic names with or without the leading '/', any subset may be missing):
- ``joint_states`` (sensor_msgs/JointState): positions (film strip, CoM) and efforts (joint load
  against the robot's URDF limits);
- ``sim/base_truth`` (nav_msgs/Odometry): base pose (CoM path, film strip); on a robot any base
  estimate published as Odometry on that topic;
- ``sim/contacts`` (climb_msgs/SimContacts): per-limb normal / tangential force and surface
  (contact forces against their friction cones; mu from the recorded scenario); without it the
  F/T sensors ``ft/*`` give |f| per sensor instead;
- ``controller/state`` (climb_msgs/ControllerState): FSM state over sim time (timeline,
  transitions), tick and QP times;
- ``climb/request`` (std_msgs/String, JSON): robot and scenario (spec YAML text or ladder name),
  for the robot model (limits, CoM) and the film strip's world;
- ``whole_body_plan``: the plans sent (count, transitions).
The film strip is re-rendered in a headless PyBullet (DIRECT, TinyRenderer): the recorded robot
and scenario, the robot set to the recorded joint positions and base pose (fingers open).
"""
from __future__ import annotations

import json
import pathlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from climb_core.errors import SpecError

_NS = 1_000_000_000


def _name(topic: str) -> str:
    return topic.lstrip("/")


def _stamp(header) -> int:
    return int(header.stamp.sec) * _NS + int(header.stamp.nanosec)


@dataclass
class RunData:
    """Time series of one recorded run; times in seconds of sim time (message stamps) unless
    said otherwise; ``*_log_ns`` are the bag's receive times [ns, wall clock]."""

    path: str = ""
    topics: dict[str, int] = field(default_factory=dict)  # topic (no leading '/') -> message count
    request: dict = field(default_factory=dict)  # climb/request JSON (the last one)
    joint_names: list[str] = field(default_factory=list)
    js_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    js_q: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    js_effort: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    base_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    base_pose: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))  # x y z qx qy qz qw
    cs_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cs_log_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    fsm: list[str] = field(default_factory=list)
    transition: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    tick_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    qp_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    qp_failures: int = 0
    plans_taken: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # per state (0: older bags)
    mode: str = ""
    contacts_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    limbs: list[str] = field(default_factory=list)
    normal: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    tangential: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    surface: list[list[str]] = field(default_factory=list)
    grasped: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))
    fell: bool = False
    fall_reason: str = ""
    ft: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # sensor -> (t, (n, 3) force)
    climb_result: dict = field(default_factory=dict)  # the summary of the last finished climb (climb/status)
    plans_log_ns: list[int] = field(default_factory=list)
    plans_transitions: list[int] = field(default_factory=list)
    #: [ns] per plan the controller accepted (its controller/plan diagnostic), the stamp of its last
    #: tick before it (None: the plan started at an activation, or a bag without the value)
    plans_after_tick_ns: list = field(default_factory=list)

    @property
    def robot(self) -> str:
        return str(self.request.get("robot") or "g1")

    @property
    def scenario_name(self) -> str:
        name = str(self.request.get("scenario_name") or "")
        if name:
            return name
        return "custom scenario" if "\n" in self.scenario else pathlib.Path(self.scenario).name

    @property
    def scenario(self) -> str:
        return str(self.request.get("scenario") or self.request.get("ladder") or "default")


def deserialize(store, raw: bytes, msgtype: str):
    """A CDR message decoded by a rosbags typestore, tolerating trailing bytes after the message
    (rmw's serialization may end with a few bytes of padding that rosbags' strict check refuses)."""
    if len(raw) < 4 or bytes(raw[:2]) not in (b"\x00\x00", b"\x00\x01"):
        raise SpecError("bag.message", f"{msgtype}: not a CDR payload")
    msgdef = store.get_msgdef(msgtype)
    func = msgdef.deserialize_cdr_le if raw[1] else msgdef.deserialize_cdr_be
    return func(bytes(raw[4:]), 0, msgdef.cls, store)[0]


def load_run(path: str | pathlib.Path, *, max_rate_hz: float | None = None) -> RunData:
    """Decode a bag's topics into a RunData (messages of a sim reset's earlier run are dropped:
    the series keep the last run of increasing stamps of each topic). ``max_rate_hz`` decimates
    joint_states / base truth / contacts (None: every message)."""
    from rosbags.highlevel import AnyReader

    from msgs_py.bag import make_typestore, recover_bag

    path = pathlib.Path(path)
    if not path.exists():
        raise SpecError("bag", f"{path} does not exist")
    if not (path / "metadata.yaml").is_file():
        recover_bag(path)  # an old recorder killed mid-run: make it readable first
    run = RunData(path=str(path))
    js_t, js_q, js_e = [], [], []
    base_t, base_pose = [], []
    cs = []
    ct, cn, ctg, csurf, cgr = [], [], [], [], []
    ft: dict[str, list] = {}
    periodic: list | None = None  # the plans' after_tick_ns as the controller's last periodic diagnostic lists them
    min_dt = 0.0 if not max_rate_hz else 1.0 / max_rate_hz
    last = {"js": -1e9, "base": -1e9, "contacts": -1e9}
    with AnyReader([path], default_typestore=make_typestore()) as reader:
        run.topics = {_name(c.topic): c.msgcount for c in reader.connections}
        wanted = [c for c in reader.connections
                  if _name(c.topic) in ("joint_states", "sim/base_truth", "controller/state", "sim/contacts",
                                        "climb/request", "whole_body_plan", "climb/status", "diagnostics")
                  or _name(c.topic).startswith("ft/")]
        for conn, log_ns, raw in reader.messages(connections=wanted):
            topic = _name(conn.topic)
            if topic == "diagnostics":
                data = bytes(raw)
                if b"accepted whole_body_plan" in data:  # decode only the plan acceptances
                    run.plans_after_tick_ns.extend(plan_acceptances(deserialize(reader.typestore, raw, conn.msgtype)))
                elif b"plans_after_tick_ns" in data:  # the controller's periodic diagnostics repeat them
                    repeated = repeated_acceptances(deserialize(reader.typestore, raw, conn.msgtype))
                    if repeated is not None:
                        periodic = repeated
                continue
            msg = deserialize(reader.typestore, raw, conn.msgtype)
            if topic == "joint_states":
                t = _stamp(msg.header) / _NS
                if t < last["js"]:  # a reset: start over
                    js_t, js_q, js_e = [], [], []
                elif t == last["js"] or t - last["js"] < min_dt:  # a state the bridge sent again, or decimated
                    continue
                last["js"] = t
                if not run.joint_names:
                    run.joint_names = list(msg.name)
                if list(msg.name) != run.joint_names:
                    continue
                js_t.append(t)
                js_q.append(np.asarray(msg.position, float))
                e = np.asarray(msg.effort, float)
                js_e.append(e if len(e) == len(run.joint_names) else np.full(len(run.joint_names), np.nan))
            elif topic == "sim/base_truth":
                t = _stamp(msg.header) / _NS
                if t < last["base"]:
                    base_t, base_pose = [], []
                elif t == last["base"] or t - last["base"] < min_dt:
                    continue
                last["base"] = t
                p, o = msg.pose.pose.position, msg.pose.pose.orientation
                base_t.append(t)
                base_pose.append((p.x, p.y, p.z, o.x, o.y, o.z, o.w))
            elif topic == "controller/state":
                t = _stamp(msg.header) / _NS
                if cs and t < cs[-1][0]:
                    cs = []
                cs.append((t, int(log_ns), msg.fsm_state, int(msg.transition_index), float(msg.tick_time_ms),
                           float(msg.qp_solve_time_ms), int(msg.qp_failures), msg.mode,
                           int(getattr(msg, "plans_taken", 0))))
            elif topic == "sim/contacts":
                t = _stamp(msg.header) / _NS
                if t < last["contacts"]:
                    ct, cn, ctg, csurf, cgr = [], [], [], [], []
                elif t - last["contacts"] < min_dt:
                    if msg.fell and not run.fell:
                        run.fell, run.fall_reason = True, msg.fall_reason
                    continue
                last["contacts"] = t
                if not run.limbs:
                    run.limbs = list(msg.limbs)
                if list(msg.limbs) != run.limbs:
                    continue
                ct.append(t)
                cn.append(np.asarray(msg.normal_force, float))
                ctg.append(np.asarray(msg.tangential_force, float))
                csurf.append(list(msg.surface))
                cgr.append(np.asarray(msg.grasped, bool))
                if msg.fell and not run.fell:
                    run.fell, run.fall_reason = True, msg.fall_reason
            elif topic.startswith("ft/"):
                t = _stamp(msg.header) / _NS
                f = msg.wrench.force
                series = ft.setdefault(topic[3:], [])
                if series and t < series[-1][0]:
                    series.clear()
                if series and (t == series[-1][0] or t - series[-1][0] < min_dt):
                    continue
                series.append((t, (f.x, f.y, f.z)))
            elif topic == "climb/request":
                try:
                    doc = json.loads(msg.data)
                    run.request = doc if isinstance(doc, dict) else {"value": doc}
                except (ValueError, TypeError):
                    run.request = {"text": msg.data}
            elif topic == "climb/status":
                if msg.phase in ("done", "failed", "cancelled"):
                    try:
                        doc = json.loads(msg.text)
                    except (ValueError, TypeError):
                        doc = {"text": msg.text}
                    run.climb_result = {"phase": msg.phase, **(doc if isinstance(doc, dict) else {"value": doc})}
            elif topic == "whole_body_plan":
                run.plans_log_ns.append(int(log_ns))
                run.plans_transitions.append(len(msg.transitions))
                if not run.request and msg.request_json:
                    try:
                        run.request = dict(json.loads(msg.request_json))
                    except (ValueError, TypeError):
                        pass
    if periodic is not None and len(run.plans_after_tick_ns) != len(run.plans_log_ns) \
            and len(periodic) == len(run.plans_log_ns):
        run.plans_after_tick_ns = periodic  # an acceptance the recorder missed (matched late)
    run.js_t = np.asarray(js_t)
    n = len(run.joint_names)
    run.js_q = np.asarray(js_q, float).reshape(len(js_t), n)
    run.js_effort = np.asarray(js_e, float).reshape(len(js_t), n)
    run.base_t = np.asarray(base_t)
    run.base_pose = np.asarray(base_pose, float).reshape(-1, 7)
    if cs:
        run.cs_t = np.array([c[0] for c in cs])
        run.cs_log_ns = np.array([c[1] for c in cs], np.int64)
        run.fsm = [c[2] for c in cs]
        run.transition = np.array([c[3] for c in cs])
        run.tick_ms = np.array([c[4] for c in cs])
        run.qp_ms = np.array([c[5] for c in cs])
        run.qp_failures = max(c[6] for c in cs)
        run.mode = cs[-1][7]
        run.plans_taken = np.array([c[8] for c in cs], np.int64)
    run.contacts_t = np.asarray(ct)
    k = len(run.limbs)
    run.normal = np.asarray(cn, float).reshape(len(ct), k)
    run.tangential = np.asarray(ctg, float).reshape(len(ct), k)
    run.surface = csurf
    run.grasped = np.asarray(cgr, bool).reshape(len(ct), k)
    run.ft = {s: (np.array([x[0] for x in v]), np.array([x[1] for x in v], float).reshape(-1, 3))
              for s, v in ft.items()}
    return run


# -- FSM timeline ------------------------------------------------------------------------------------

def fsm_segments(t: np.ndarray, states: list[str]) -> list[tuple[str, float, float]]:
    """(state, start [s], end [s]) of each stretch of one FSM state."""
    out: list[tuple[str, float, float]] = []
    for ti, s in zip(t, states):
        if out and out[-1][0] == s:
            out[-1] = (s, out[-1][1], float(ti))
        else:
            if out:
                out[-1] = (out[-1][0], out[-1][1], float(ti))
            out.append((s, float(ti), float(ti)))
    return out


def plan_acceptances(msg) -> list:
    """The after_tick_ns [ns] (None when empty or unreadable) of each controller/plan status of a
    DiagnosticArray that says a whole_body_plan was accepted."""
    out = []
    for status in msg.status:
        if status.name.endswith("controller/plan") and status.message.startswith("accepted whole_body_plan"):
            value = {kv.key: kv.value for kv in status.values}.get("after_tick_ns", "")
            try:
                out.append(int(value) if value else None)
            except ValueError:
                out.append(None)
    return out


def repeated_acceptances(msg) -> list | None:
    """The plans' after_tick_ns [ns] (None for -1: started at an activation) that a controller's
    periodic diagnostic repeats (value ``plans_after_tick_ns``); None when it has none."""
    for status in msg.status:
        values = {kv.key: kv.value for kv in status.values}
        if status.name == "controller" and "plans_after_tick_ns" in values:
            out = []
            for item in filter(None, values["plans_after_tick_ns"].split(",")):
                try:
                    out.append(int(item) if int(item) >= 0 else None)
                except ValueError:
                    out.append(None)
            return out
    return None


def first_tick_after(stamps_ns, after_ns: int) -> int | None:
    """[ns] the first of ``stamps_ns`` (a controller's state stamps, in order) later than
    ``after_ns``, or None."""
    for s in stamps_ns:
        if s > after_ns:
            return int(s)
    return None


def plan_taking_stamps(stamps_ns, counts, plans: int) -> list[int] | None:
    """[ns] the first tick of each of ``plans`` plans from a controller's states (stamps in order)
    and their plans_taken counts: the states whose count went up from the state before (twice for
    two plans taken between two ticks), and the first state when it already counts one plan that
    no other state does (a plan taken on the first tick). None when the counts do not account for
    exactly ``plans`` plans (older bags carry no count: all zero)."""
    counts = [int(c) for c in counts]
    if not counts:
        return None
    out = []
    for i in range(1, len(counts)):
        out.extend([int(stamps_ns[i])] * max(0, counts[i] - counts[i - 1]))
    if len(out) == plans - 1 and counts[0] >= 1:
        out.insert(0, int(stamps_ns[0]))
    return out if len(out) == plans and plans > 0 else None


def plan_start_stamps(run: RunData, from_acceptance: bool = True) -> list[int]:
    """[ns] for each recorded whole_body_plan, the sim stamp of the first controller tick that
    acted on it. First the controller's own count (controller/state's plans_taken: the states
    whose count went up, plan_taking_stamps), which rides on every state and so is not missed
    when the recorder matched the controller's diagnostics late. Else, when the controller said
    after which tick it accepted each plan (its controller/plan diagnostic's after_tick_ns), the
    first controller/state after that tick: sim
    time alone, whatever order the recorder received the topics in. Else (older bags, a plan that
    started at an activation) the first controller/state received after the plan whose FSM state
    differs from the one before it (the FSM leaves idle / hold on the tick it takes a plan), or
    that starts a run (the first state, or the first after a sim reset: a controller activated
    once its plan exists takes it on its first tick). ``from_acceptance=False``: that second rule
    only (to compare with a run whose acceptances and counts are not known)."""
    out = []
    if not len(run.cs_t):
        return out
    stamps = [int(round(t * _NS)) for t in run.cs_t]
    taken = plan_taking_stamps(stamps, run.plans_taken, len(run.plans_log_ns)) if from_acceptance else None
    if taken is not None:
        return taken
    if from_acceptance and len(run.plans_after_tick_ns) == len(run.plans_log_ns) \
            and all(a is not None for a in run.plans_after_tick_ns):
        starts = [first_tick_after(stamps, a) for a in run.plans_after_tick_ns]
        if all(s is not None for s in starts):
            return starts
    for log_ns in run.plans_log_ns:
        after = np.nonzero(run.cs_log_ns >= log_ns)[0]
        stamp = None
        for i in after:
            if i == 0 or run.cs_t[i] < run.cs_t[i - 1] or run.fsm[i] != run.fsm[i - 1]:
                stamp = int(round(run.cs_t[i] * _NS))
                break
        if stamp is None and len(after):
            stamp = int(round(run.cs_t[after[0]] * _NS))
        if stamp is not None:
            out.append(stamp)
    return out


# -- trajectory comparison (replay --reexecute) ------------------------------------------------------

def compare_base(t_a: np.ndarray, p_a: np.ndarray, t_b: np.ndarray, p_b: np.ndarray) -> dict:
    """Base position deviation of run b from run a at the sim stamps both have (exact stamps,
    1 µs tolerance): max and RMS [mm], number of stamps compared and the stamp of the max."""
    ka = np.round(np.asarray(t_a) * 1e6).astype(np.int64)
    kb = np.round(np.asarray(t_b) * 1e6).astype(np.int64)
    common, ia, ib = np.intersect1d(ka, kb, return_indices=True)
    if not len(common):
        return {"compared": 0, "max_mm": None, "rms_mm": None, "at_s": None}
    d = np.linalg.norm(np.asarray(p_a)[ia, :3] - np.asarray(p_b)[ib, :3], axis=1) * 1e3
    j = int(np.argmax(d))
    return {"compared": int(len(common)), "max_mm": round(float(d[j]), 4),
            "rms_mm": round(float(np.sqrt(np.mean(d ** 2))), 4), "at_s": round(float(common[j]) * 1e-6, 4),
            "from_s": round(float(common[0]) * 1e-6, 4), "to_s": round(float(common[-1]) * 1e-6, 4)}


# -- the robot model and the scenario ---------------------------------------------------------------

def _robot(run: RunData):
    from climb_core.robot import load_robot

    return load_robot(run.robot)


def _environment(run: RunData):
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario

    return build_environment(load_scenario(run.scenario))


def configuration(robot, joint_names: list[str], positions: np.ndarray, base_pose: np.ndarray) -> np.ndarray:
    """Pinocchio q of ``robot`` from a JointState's names / positions and a base pose (x y z, qxyzw)."""
    q = np.array(robot.model.referenceConfigurations["neutral"] if "neutral" in robot.model.referenceConfigurations
                 else np.zeros(robot.model.nq), float)
    q[:7] = base_pose
    index = {n: i for i, n in enumerate(joint_names)}
    for name in robot.joint_names:
        if name in index:
            jid = robot.model.getJointId(name)
            q[robot.model.joints[jid].idx_q] = positions[index[name]]
    return q


def _base_at(run: RunData, t: np.ndarray) -> np.ndarray:
    """Base poses at times t (nearest sample)."""
    if not len(run.base_t):
        return np.tile(np.array([0.0, 0.0, 0.8, 0.0, 0.0, 0.0, 1.0]), (len(t), 1))
    i = np.clip(np.searchsorted(run.base_t, t), 0, len(run.base_t) - 1)
    return run.base_pose[i]


def com_path(run: RunData, robot, max_points: int = 600) -> tuple[np.ndarray, np.ndarray]:
    """(t, (n, 3) CoM [m]) from joint_states + base pose through the robot model."""
    import pinocchio as pin

    if not len(run.js_t):
        return np.zeros(0), np.zeros((0, 3))
    idx = np.unique(np.linspace(0, len(run.js_t) - 1, min(max_points, len(run.js_t))).astype(int))
    data = robot.model.createData()
    base = _base_at(run, run.js_t[idx])
    out = np.array([pin.centerOfMass(robot.model, data, configuration(robot, run.joint_names, run.js_q[i], b))
                    for i, b in zip(idx, base)])
    return run.js_t[idx], out.reshape(-1, 3)


def effort_limits(robot, joint_names: list[str]) -> np.ndarray:
    """[N m] URDF effort limit of each named joint (nan when the model has none)."""
    out = np.full(len(joint_names), np.nan)
    model = robot.model
    for k, name in enumerate(joint_names):
        if model.existJointName(name):
            j = model.joints[model.getJointId(name)]
            if j.nv == 1:
                limit = float(model.effortLimit[j.idx_v])
                out[k] = limit if limit > 0 else np.nan
    return out


# -- figures -----------------------------------------------------------------------------------------

def plot_report(run: RunData, path: str | pathlib.Path, robot=None, env=None, n_joints: int = 4) -> pathlib.Path:
    """report.png: CoM path, contact forces against their cones, the most loaded joints against
    their limits, controller tick times, FSM timeline."""
    from .plots import _pyplot, _save

    plt = _pyplot()
    fig = plt.figure(figsize=(14, 12))
    grid = fig.add_gridspec(3, 2, height_ratios=[1, 1, 0.55])
    # CoM path (side view) with the base path
    ax = fig.add_subplot(grid[0, 0])
    if robot is not None and len(run.js_t):
        t, com = com_path(run, robot)
        sc = ax.scatter(com[:, 0], com[:, 2], c=t, s=3, cmap="viridis", label="CoM")
        fig.colorbar(sc, ax=ax, label="t [s]")
    if len(run.base_t):
        ax.plot(run.base_pose[:, 0], run.base_pose[:, 2], color="0.6", lw=0.8, label="base")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.set_title("CoM path (side view)")
    ax.axis("equal")
    ax.legend(loc="best", fontsize=8)
    # contact forces against their friction cones
    ax = fig.add_subplot(grid[0, 1])
    if len(run.contacts_t) and run.limbs:
        mu_of = {name: float(s.friction) for name, s in env.surfaces.items()} if env is not None else {}
        for k, limb in enumerate(run.limbs):
            use, tt = [], []
            for i, ti in enumerate(run.contacts_t):
                fn, ftan = run.normal[i, k], run.tangential[i, k]
                grasped = bool(run.grasped[i, k]) if run.grasped.size else False
                if fn < 1.0 or grasped:
                    continue
                mu = mu_of.get(run.surface[i][k], np.nan)
                tt.append(ti)
                use.append(ftan / (mu * fn))
            if tt:
                ax.plot(tt, use, ".", ms=2, label=limb)
        ax.axhline(1.0, color="r", lw=1.0, ls="--", label="friction cone")
        ax.set_ylim(0.0, 1.5)
        ax.set_ylabel("|f_t| / (mu f_n) [-]")
        ax.set_title("contact forces against their friction cones (sim/contacts; grasps excluded)")
    elif run.ft:
        for sensor, (t, f) in sorted(run.ft.items()):
            ax.plot(t, np.linalg.norm(f, axis=1), lw=0.7, label=sensor)
        ax.set_ylabel("|f| [N]")
        ax.set_title("F/T sensor forces (no sim/contacts in the bag)")
    ax.set_xlabel("t [s]")
    ax.legend(loc="upper right", fontsize=8, markerscale=4)
    # the most loaded joints against their limits
    ax = fig.add_subplot(grid[1, 0])
    if robot is not None and len(run.js_t) and np.isfinite(run.js_effort).any():
        limits = effort_limits(robot, run.joint_names)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.nanmax(np.abs(run.js_effort), axis=0) / limits
        ratio = np.where(np.isfinite(ratio), ratio, -1.0)
        for j in np.argsort(ratio)[::-1][:n_joints]:
            if ratio[j] < 0:
                continue
            ax.plot(run.js_t, run.js_effort[:, j] / limits[j], lw=0.8,
                    label=f"{run.joint_names[j]} (limit {limits[j]:.0f} N m)")
        ax.axhline(1.0, color="r", lw=1.0, ls="--")
        ax.axhline(-1.0, color="r", lw=1.0, ls="--")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("effort / limit [-]")
    ax.set_title(f"the {n_joints} most loaded joints (joint_states effort)")
    ax.legend(loc="lower left", fontsize=8)
    # tick times
    ax = fig.add_subplot(grid[1, 1])
    if len(run.tick_ms):
        ax.plot(run.cs_t, run.tick_ms, ",", color="C0", alpha=0.5)
        for q, ls in ((50, "-"), (99, "--")):
            v = float(np.percentile(run.tick_ms, q))
            ax.axhline(v, color="k", ls=ls, lw=0.8, label=f"p{q} {v:.2f} ms")
        ax.axhline(5.0, color="r", lw=1.0, label="control period 5 ms")
        ax.set_yscale("log")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("tick [ms]")
    ax.set_title("controller tick time (state in -> command out)")
    ax.legend(loc="upper right", fontsize=8)
    # FSM timeline
    ax = fig.add_subplot(grid[2, :])
    draw_fsm_timeline(ax, run)
    where = run.scenario_name
    fig.suptitle(f"{run.robot} on {where} ({run.mode or '?'} mode): {pathlib.Path(run.path).name}")
    return _save(plt, fig, path)


def draw_fsm_timeline(ax, run: RunData) -> None:
    segments = fsm_segments(run.cs_t, run.fsm)
    names = list(dict.fromkeys(s for s, _, _ in segments))
    colors = {n: f"C{i % 10}" for i, n in enumerate(names)}
    for s, t0, t1 in segments:
        ax.barh(0, max(t1 - t0, 0.005), left=t0, color=colors[s], edgecolor="none")
    if len(run.cs_t):
        trans = np.nonzero(np.diff(run.transition) != 0)[0]
        for i in trans:
            ax.axvline(run.cs_t[i + 1], color="k", lw=0.5, alpha=0.5)
    from matplotlib.patches import Patch

    handles = [Patch(color=colors[n], label=n) for n in names]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.35), ncol=min(len(names), 8) or 1,
              fontsize=8)
    ax.set_yticks([])
    ax.set_xlabel("t [s] (sim time; black lines: a new plan transition)")
    ax.set_title("controller FSM state over time")


def film_frames(run: RunData, n: int = 8, settings=None) -> list[tuple[float, np.ndarray]]:
    """``n`` (time, RGB) frames of the recorded run, re-rendered in a headless PyBullet from the
    recorded robot, scenario, joint positions and base pose."""
    from sim_bridge.backend import ResetRequest
    from sim_bridge.pybullet_backend import PyBulletBackend

    from .climb import snapshot
    from .settings import load_climb_settings

    if not len(run.js_t) or n <= 0:
        return []
    cs = settings or load_climb_settings()
    backend = PyBulletBackend()
    try:
        backend.reset(ResetRequest(robot=run.robot, ladder=run.scenario))
        robot = backend.robot
        frames = []
        times = np.linspace(run.js_t[0], run.js_t[-1], n)
        idx = np.clip(np.searchsorted(run.js_t, times), 0, len(run.js_t) - 1)
        bases = _base_at(run, run.js_t[idx])
        for i, base in zip(idx, bases):
            backend.set_state(configuration(robot, run.joint_names, run.js_q[i], base))
            frames.append((float(run.js_t[i]), snapshot(backend, cs)))
        return frames
    finally:
        backend.close()


def summary(run: RunData) -> dict:
    """Figures of the run for report.md (and a test)."""
    segments = fsm_segments(run.cs_t, run.fsm)
    out: dict[str, Any] = {
        "bag": run.path, "robot": run.robot, "mode": run.mode,
        "topics": dict(sorted(run.topics.items())),
        "sim_time_s": round(float(max([x[-1] for x in (run.js_t, run.cs_t, run.base_t) if len(x)], default=0.0)), 3),
        "plans": len(run.plans_log_ns), "plan_transitions": run.plans_transitions,
        "fsm_final": run.fsm[-1] if run.fsm else "", "fsm_states": len(segments),
        "qp_failures": run.qp_failures, "fell": run.fell, "fall_reason": run.fall_reason,
        "climb_result": {k: run.climb_result.get(k) for k in ("phase", "success", "rungs_reached", "failure_reason")
                         if k in run.climb_result},
    }
    if len(run.tick_ms):
        out["tick_ms"] = {"p50": round(float(np.percentile(run.tick_ms, 50)), 3),
                          "p99": round(float(np.percentile(run.tick_ms, 99)), 3),
                          "max": round(float(run.tick_ms.max()), 3)}
    if len(run.base_t):
        out["base_start"] = [round(float(x), 4) for x in run.base_pose[0, :3]]
        out["base_end"] = [round(float(x), 4) for x in run.base_pose[-1, :3]]
    if len(run.contacts_t) and run.limbs:
        last = run.surface[-1]
        out["final_surfaces"] = {limb: last[k] for k, limb in enumerate(run.limbs)}
    return out


def write_report(run: RunData, out_dir: str | pathlib.Path, *, film: int = 8) -> dict[str, pathlib.Path]:
    """report.png, film_strip.png and report.md in ``out_dir``; returns their paths by name."""
    from .plots import film_strip

    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    robot = env = None
    notes = []
    try:
        robot = _robot(run)
    except Exception as exc:  # noqa: BLE001 - a report without the model still has the rest
        notes.append(f"robot model {run.robot!r} not loaded: {exc}")
    try:
        env = _environment(run)
    except Exception as exc:  # noqa: BLE001
        notes.append(f"scenario not loaded: {exc}")
    paths = {"report_png": plot_report(run, out / "report.png", robot, env)}
    frames = []
    if film:
        try:
            frames = film_frames(run, film)
        except Exception as exc:  # noqa: BLE001
            notes.append(f"film strip not rendered: {type(exc).__name__}: {exc}")
    if frames:
        paths["film_strip_png"] = film_strip(frames, out / "film_strip.png")
    info = summary(run)
    lines = [f"# Run report: {pathlib.Path(run.path).name}", "",
             f"- bag: `{run.path}`", f"- robot: {run.robot} on {run.scenario_name}, mode: {run.mode or '?'}",
             f"- sim time: {info['sim_time_s']} s, plans received: {info['plans']} "
             f"(transitions {info['plan_transitions']})",
             f"- final FSM state: {info['fsm_final'] or '?'}, QP failures: {run.qp_failures}, "
             f"fell: {run.fell}{' (' + run.fall_reason + ')' if run.fall_reason else ''}"]
    if run.climb_result:
        r = run.climb_result
        lines.append(f"- climb {r.get('phase')}: success {r.get('success')}, rungs reached {r.get('rungs_reached')} "
                     f"of {r.get('rungs_requested')}{', ' + str(r.get('failure_reason')) if r.get('failure_reason') else ''}")
    if "tick_ms" in info:
        lines.append(f"- controller tick: p50 {info['tick_ms']['p50']} ms, p99 {info['tick_ms']['p99']} ms, "
                     f"max {info['tick_ms']['max']} ms")
    if "final_surfaces" in info:
        lines.append(f"- final contacts: {info['final_surfaces']}")
    lines += ["", "![report](report.png)", ""]
    if frames:
        lines += ["![film strip](film_strip.png)", ""]
    lines += ["## FSM timeline", "", "| from [s] | to [s] | state |", "| ---: | ---: | --- |"]
    for s, t0, t1 in fsm_segments(run.cs_t, run.fsm):
        lines.append(f"| {t0:.3f} | {t1:.3f} | {s} |")
    lines += ["", "## Topics", "", "| topic | messages |", "| --- | ---: |"]
    for topic, count in sorted(run.topics.items()):
        lines.append(f"| {topic} | {count} |")
    if notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in notes]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    paths["report_md"] = out / "report.md"
    paths["notes"] = notes  # type: ignore[assignment]
    return paths
