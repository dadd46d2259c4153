"""Issue 20 row 1 and "clean shutdown": every executable of the graph, signalled with SIGINT or
SIGTERM at a random moment, exits 0 with no traceback.

Each executable (tests/ros/node_execs.py) gets ``RUNS`` signals in total, half SIGINT, half
SIGTERM, each to a fresh process, at a random delay of 0.3-3 s counted either from the start of
the process (imports, node construction) or from the moment its DDS participant exists (the node
running). Each executable runs in its own lane (namespace ``/sig_<name>``, the session's domain),
all lanes in parallel, with what makes it busy:

A quarter of the signals wait until the node runs: its lane's ready topic (READY_TOPICS: ticking
in lock-step, planning) has a message from it, the others until its DDS participant exists.

- sim_bridge: in lock-step with a controller that lives through the whole test (signals mid-tick);
- controller: in lock-step with a bridge that lives through the whole test (mid-tick);
- sim_graph: the bridge and the controller composed, in lock-step (mid-tick);
- primitive_adaptation: a planning request every second (mid-planning), guide_path a plan
  request every second;
- contact_search, climb_coordinator, recorder: idle.

The lane partners are stopped with SIGINT at the end and must exit 0 too. Before its handlers
exist (msgs_py.node_kit: ``install_signal_handlers()`` first thing in ``main()``) a process dies
the default way; the interpreter's own start (and the console script's entry-point lookup) is
allowed for, whatever the machine's load: a signal due while the process has neither its
handlers (/proc/<pid>/status SigCgt) nor any heavy library mapped yet (numpy, rclpy, PyBullet,
Pinocchio in /proc/<pid>/maps) waits for one of the two. A node that imports heavy modules before
installing its handlers is therefore signalled during those imports, and fails.
An executable missing from .venv/lib fails its test only when a setup.py declares it.
Reproduce a run with CLIMB_SIGNAL_SEED=<the seed printed on failure>.
"""
from __future__ import annotations

import json
import os
import pathlib
import random
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field

import pytest

from node_execs import EXECUTABLES, Executable, executable_status, sockets

pytestmark = pytest.mark.ros

RUNS = 8  # signals per executable (half SIGINT, half SIGTERM; 2 of them once it runs): 72 in all
DELAY_S = (0.3, 3.0)  # [s] random delay before the signal
EXIT_TIMEOUT_S = 30.0  # [s] a signalled process must be gone by then (busy 2-core machine)
READY_TIMEOUT_S = 90.0  # [s] a process's DDS participant exists
TOPIC_READY_S = 30.0  # [s] a process's ready topic has a message (ticking, planning)
REQUEST_PERIOD_S = 1.0  # [s] planning requests to the planning lanes
SIG_BITS = (1 << (signal.SIGINT - 1)) | (1 << (signal.SIGTERM - 1))

SEED = int(os.environ.get("CLIMB_SIGNAL_SEED", str(int(time.time()) % 100000)))


@dataclass
class Outcome:
    exe: str
    sig: str
    delay: float
    from_ready: bool
    code: int | None
    stderr_tail: str
    early: bool = False  # the signal waited for the process's handlers

    @property
    def ok(self) -> bool:
        return self.code == 0 and "Traceback" not in self.stderr_tail

    def __str__(self) -> str:
        return (f"{self.exe}: {self.sig} after {self.delay:.2f} s from {'ready' if self.from_ready else 'start'}"
                f"{' (waited for the interpreter to start)' if self.early else ''} -> exit {self.code}\n{self.stderr_tail}")


@dataclass
class Lane:
    exe: Executable
    outcomes: list[Outcome] = field(default_factory=list)
    error: str = ""


def lane_name(exe: Executable) -> str:
    return "sig_" + exe.name


def base_env() -> dict[str, str]:
    from climb_core.ros_env import local_dds_env

    return local_dds_env()


def catches_signals(pid: int) -> bool:
    """SIGINT and SIGTERM both have a handler in the process (not the default action)."""
    try:
        for line in pathlib.Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigCgt:"):
                return int(line.split()[1], 16) & SIG_BITS == SIG_BITS
    except (FileNotFoundError, ProcessLookupError):
        pass
    return False


#: shared libraries of the heavy imports: mapped = the interpreter's start is over
HEAVY_LIBRARIES = ("_multiarray_umath", "_rclpy_pybind11", "pybullet", "libpinocchio")


def heavy_loaded(pid: int) -> bool:
    try:
        maps = pathlib.Path(f"/proc/{pid}/maps").read_text()
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return True  # gone: nothing to wait for
    return any(lib in maps for lib in HEAVY_LIBRARIES)


def participant_ready(pid: int, domain_id: int) -> bool:
    base = 7400 + 250 * domain_id
    try:
        return any(s.table == "udp" and base <= s.port < base + 250 for s in sockets(pid))
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return False


def start(exe: Executable, workdir: str, tag: str, namespace: str | None = None) -> tuple[subprocess.Popen, pathlib.Path]:
    """``exe`` in its lane's namespace (or ``namespace``), stderr to a file."""
    more = ["-r", f"__ns:=/{namespace or lane_name(exe)}"]
    if exe.name == "recorder":
        more += ["-p", f"bag_path:={workdir}/bag_{tag}", "-p", "topics:=[joint_states]"]
    log = pathlib.Path(workdir) / f"{exe.name}_{tag}.err"
    with log.open("w") as err:
        proc = subprocess.Popen(exe.argv(*more), env=base_env(), cwd=workdir, stdout=subprocess.DEVNULL,
                                stderr=err, start_new_session=True)
    return proc, log


def stop(proc: subprocess.Popen, sig: int) -> int | None:
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        return proc.wait(timeout=EXIT_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return None  # hung: a failure


def run_lane(lane: Lane, rng: random.Random, workdir: str, domain_id: int, observer: "Observer") -> None:
    exe = lane.exe
    # a quarter of the signals once the node runs (ticking, planning), the rest from the start
    plan = [(signal.SIGINT if k % 2 == 0 else signal.SIGTERM, k % 4 == 3) for k in range(RUNS)]
    rng.shuffle(plan)
    try:
        for k, (sig, from_ready) in enumerate(plan):
            delay = rng.uniform(*DELAY_S)
            proc, log = start(exe, workdir, f"{k}")
            t0 = spawned = time.monotonic()
            if from_ready:
                deadline = t0 + READY_TIMEOUT_S
                while proc.poll() is None and not participant_ready(proc.pid, domain_id) \
                        and time.monotonic() < deadline:
                    time.sleep(0.05)
                if exe.name in READY_TOPICS:  # ticking / planning (or give up after TOPIC_READY_S)
                    deadline = time.monotonic() + TOPIC_READY_S
                    while proc.poll() is None and observer.seen.get(exe.name, 0.0) < spawned \
                            and time.monotonic() < deadline:
                        time.sleep(0.02)
                t0 = time.monotonic()
            while proc.poll() is None and time.monotonic() < t0 + delay:
                time.sleep(0.02)
            early = False
            if proc.poll() is None and not catches_signals(proc.pid) and not heavy_loaded(proc.pid):
                early = True  # the interpreter is still starting: wait for the handlers or the heavy imports
                deadline = time.monotonic() + READY_TIMEOUT_S
                while proc.poll() is None and not catches_signals(proc.pid) and not heavy_loaded(proc.pid) \
                        and time.monotonic() < deadline:
                    time.sleep(0.005)
            exited_before = proc.poll() is not None
            code = stop(proc, sig)
            text = log.read_text(errors="replace")
            if exited_before:
                text = f"(exited by itself before the signal)\n{text}"
                code = code if code != 0 else -999  # a node must not end on its own here
            lane.outcomes.append(Outcome(str(exe), sig.name, delay, from_ready, code, text[-2500:], early))
    except Exception as err:  # noqa: BLE001 - reported by the test of this lane
        lane.error = f"{type(err).__name__}: {err}"


#: executable -> (topic in its lane, type) whose first message after the start means "running":
#: ticking in lock-step, planning; the others are running once their DDS participant exists
READY_TOPICS = {"sim_bridge": ("joint_states", "sensor_msgs.msg.JointState"),
                "sim_graph": ("joint_states", "sensor_msgs.msg.JointState"),
                "controller": ("joint_command", "climb_msgs.msg.JointCommand"),
                "primitive_adaptation": ("primitive_adaptation/status", "climb_msgs.msg.ClimbStatus"),
                "guide_path": ("guide_path/status", "climb_msgs.msg.ClimbStatus")}


def _type(path: str):
    import importlib

    module, name = path.rsplit(".", 1)
    return getattr(importlib.import_module(module), name)


class Observer:
    """An rclpy node of its own context, spun in a thread: publishes planning requests to the
    planning lanes every REQUEST_PERIOD_S and notes when each lane's ready topic last had a message."""

    def __init__(self, targets: list[tuple[str, str]], watch: dict[str, tuple[str, str]]):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import String

        from msgs_py.topics import qos_for

        self.rclpy, self.String = rclpy, String
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("signal_test_observer", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.pubs = [(self.node.create_publisher(String, topic, qos_for(topic)), text) for topic, text in targets]
        self.seen: dict[str, float] = {}  # lane -> monotonic time of its ready topic's last message
        for lane, (topic, type_path) in watch.items():
            self.node.create_subscription(_type(type_path), topic, lambda _msg, lane=lane: self._saw(lane),
                                          qos_for(topic), raw=True)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _saw(self, lane: str) -> None:
        self.seen[lane] = time.monotonic()

    def _run(self) -> None:
        k, next_request = 0, time.monotonic()
        while not self._stop.is_set():
            try:
                self.executor.spin_once(timeout_sec=0.05)
                if time.monotonic() >= next_request:
                    k += 1
                    next_request += REQUEST_PERIOD_S
                    for pub, text in self.pubs:
                        pub.publish(self.String(data=text.replace("@K", str(k))))
            except Exception:  # noqa: BLE001 - the context is going away
                return

    def close(self) -> None:
        self._stop.set()
        self.thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


@pytest.fixture(scope="module")
def lanes():
    domain_id = int(os.environ["ROS_DOMAIN_ID"])
    rng = random.Random(SEED)
    workdir = tempfile.mkdtemp(prefix="signals_")
    by_name = {e.name: e for e in EXECUTABLES}
    only = [n for n in os.environ.get("CLIMB_SIGNAL_ONLY", "").split(",") if n]  # debugging: some lanes only
    installed = [e for e in EXECUTABLES if executable_status(e) == "installed" and (not only or e.name in only)]
    partners: list[tuple[str, subprocess.Popen, pathlib.Path]] = []
    # lock-step partners: a controller for the bridge's lane, a bridge for the controller's
    for partner, lane_of in (("controller", "sim_bridge"), ("sim_bridge", "controller")):
        if partner in by_name and lane_of in {e.name for e in installed} and \
                executable_status(by_name[partner]) == "installed":
            proc, log = start(by_name[partner], workdir, "partner", lane_name(by_name[lane_of]))
            partners.append((f"{partner} (partner of {lane_of})", proc, log))
    requests = [(f"/{lane_name(by_name['primitive_adaptation'])}/primitive_adaptation/request",
                 json.dumps({"ladder": "default", "robot": "g1", "steps": 2, "id": "signals-@K"})),
                (f"/{lane_name(by_name['guide_path'])}/plan/request",
                 json.dumps({"id": "signals-@K", "robot": "g1", "scenario": "default", "rungs": 2, "seed": 0}))]
    print(f"signal test: seed {SEED}")
    observer = Observer(requests, {e.name: (f"/{lane_name(e)}/{READY_TOPICS[e.name][0]}", READY_TOPICS[e.name][1])
                                   for e in installed if e.name in READY_TOPICS})
    result: dict[str, Lane] = {e.name: Lane(e) for e in installed}
    threads = [threading.Thread(target=run_lane, args=(lane, random.Random(rng.random()), workdir, domain_id,
                                                       observer), daemon=True)
               for lane in result.values()]
    try:
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=900)
        partner_outcomes = []
        for name, proc, log in partners:
            alive = proc.poll() is None
            code = stop(proc, signal.SIGINT)
            text = log.read_text(errors="replace")
            partner_outcomes.append(Outcome(name, "SIGINT", 0.0, True, code if alive else -999,
                                            ("" if alive else "(died during the test)\n") + text[-2500:]))
        yield result, partner_outcomes
    finally:
        observer.close()
        for _, proc, _ in partners:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


@pytest.mark.parametrize("exe", EXECUTABLES, ids=str)
def test_signal_at_any_moment_exits_zero(lanes, exe):
    status = executable_status(exe)
    if status == "undeclared":
        pytest.skip(f"{exe}: no such executable and no setup.py entry point declares it")
    assert status == "installed", f"{exe} is declared in src/{exe.package}/setup.py but not installed " \
                                  f"at {exe.path} (make setup)"
    result, _ = lanes
    if exe.name not in result:
        pytest.skip(f"{exe}: not in CLIMB_SIGNAL_ONLY")
    lane = result[exe.name]
    assert not lane.error, f"{exe}: {lane.error} (seed {SEED})"
    assert len(lane.outcomes) == RUNS, f"{exe}: {len(lane.outcomes)} of {RUNS} runs (seed {SEED})"
    assert {o.sig for o in lane.outcomes} == {"SIGINT", "SIGTERM"}
    bad = [o for o in lane.outcomes if not o.ok]
    assert not bad, f"{len(bad)} of {RUNS} stops of {exe} failed (seed {SEED}):\n\n" + "\n\n".join(map(str, bad))


def test_lockstep_partners_exit_zero(lanes):
    _, partners = lanes
    bad = [o for o in partners if not o.ok]
    assert not bad, "\n\n".join(map(str, bad))
