"""The rclpy side shared by the planning nodes (guide_path, contact_search, primitive_adaptation).

A stage node declares its parameters from its schema (descriptions, ranges, validation on set:
msgs_py.node_kit), publishes ClimbStatus on ``<stage>/status`` and runs one request at a time in a
worker thread. Every status carries the id of the request it concerns, a refused one included:

- the request's phase (``guide_path``, ``contact_search``, ``adaptation``) when its work starts and
  every ``STATUS_PERIOD_S`` while it runs (step k of n where the stage counts them);
- ``done`` with the stage's JSON summary as text, published just BEFORE the product (a client
  waiting for the product finds the summary there; DDS does not order two topics, but one writer's
  samples leave in order); no progress status follows a request's done / failed;
- ``failed`` with the reason: a malformed input (field and rule), a strategy not implemented, a
  violated constraint, "busy" (another request is being planned: this one is refused, not
  queued), or an internal error (the node keeps serving).

Imports rclpy: only the node modules' main() import this module.
"""
from __future__ import annotations

import json
import threading
import time
from typing import Any, Callable

from climb_msgs.msg import ClimbStatus
from rclpy.node import Node

from climb_core.errors import ClimbError, InfeasibleError, SpecError
from msgs_py.node_kit import Worker, declare_from_schema, decode, diagnose, guarded, safe_publish
from msgs_py.stamps import make_header
from msgs_py.topics import qos_for

#: [s] period of the progress status while a request is worked on
STATUS_PERIOD_S = 0.5


class StageNode(Node):
    """A planning stage: parameters, status topic, worker, request bookkeeping."""

    def __init__(self, node_name: str, schema: type, defaults: Any, phase: str, *,
                 read_only: tuple[str, ...] = ()) -> None:
        super().__init__(node_name)
        self.phase = phase
        self.params = declare_from_schema(self, schema, defaults, read_only=read_only, on_change=self._set_params)
        self.status_topic = f"{node_name}/status"
        self.pub_status = self.create_publisher(ClimbStatus, self.status_topic, qos_for(self.status_topic))
        self.worker = Worker(self, f"{node_name}_worker", on_error=self._job_crashed)
        self._progress = (0, 0)
        #: the request being worked on; cleared, under the lock, as its last status goes out, so no
        #: progress status of the timer can follow its done / failed
        self._active: str | None = None
        self._status_lock = threading.Lock()
        self.create_timer(STATUS_PERIOD_S, guarded(self, self._tick, "status_timer"))

    def warm_up(self, settings: Any, robot: str = "g1") -> None:
        """Load the default robot, ladder, library and start fixture in a background thread (the
        models are cached per process: the first request then starts planning at once)."""
        from .pipeline import warm_up

        def run() -> None:
            t0 = time.perf_counter()
            try:
                warm_up(settings, robot)
            except Exception as exc:  # noqa: BLE001 - only a head start: a request reports real errors
                if not self.worker.stopping:
                    self.get_logger().warning(f"warm-up: {type(exc).__name__}: {exc}")
                return
            if not self.worker.stopping:
                self.get_logger().info(f"warm-up done in {time.perf_counter() - t0:.1f} s")

        threading.Thread(target=run, name=f"{self.get_name()}_warm_up", daemon=True).start()

    # -------------------------------------------------------------- inputs
    def subscribe(self, msg_type: type, topic: str, handler: Callable[[Any], None]) -> None:
        """A raw subscription decoded in a guarded callback: bytes that are not a ``msg_type`` are
        reported on ``diagnostics`` (the type and the size) instead of failing in the executor."""
        def on_bytes(data: bytes) -> None:
            try:
                msg = decode(data, msg_type)
            except ValueError as exc:
                self.get_logger().warning(f"{topic}: {exc}")
                diagnose(self, f"{self.get_name()}/{topic}", f"rejected {topic}: {exc}", values={"bytes": len(data)})
                return
            handler(msg)

        self.create_subscription(msg_type, topic, guarded(self, on_bytes, topic), qos_for(topic), raw=True)

    # -------------------------------------------------------------- parameters
    def _set_params(self, new: Any) -> None:
        self.params = new

    # -------------------------------------------------------------- status
    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def status(self, request_id: str, phase: str, text: str = "", step: int = 0, n: int = 0) -> bool:
        msg = ClimbStatus(header=make_header(self.now_s()), id=str(request_id), phase=phase, step=int(max(0, step)),
                          n_steps=int(max(0, n)), progress=float(min(1.0, step / n)) if n else 0.0,
                          text=text[:20000])
        return safe_publish(self.pub_status, msg)

    def fail(self, request_id: str, text: str) -> None:
        """A failed status for a request that is not (or not yet) worked on: malformed, refused."""
        self.get_logger().warning(f"request {request_id!r} failed: {text[:500]}")
        self.status(request_id, "failed", text)

    def finish(self, request_id: str, phase: str, text: str, step: int = 0, n: int = 0) -> None:
        """The last status (done / failed) of the request being worked on."""
        if phase == "failed":
            self.get_logger().warning(f"request {request_id!r} failed: {text[:500]}")
        with self._status_lock:
            if self._active == request_id:
                self._active = None
            self.status(request_id, phase, text, step, n)

    def done(self, request_id: str, summary: dict, n: int = 0) -> None:
        self.finish(request_id, "done", json.dumps(summary), n, n)

    def set_progress(self, k: int, n: int) -> None:
        with self._status_lock:
            self._progress = (int(k), int(n))

    def _tick(self) -> None:
        with self._status_lock:
            if self._active is not None:
                k, n = self._progress
                self.status(self._active, self.phase, "planning", k, n)

    # -------------------------------------------------------------- requests
    def start(self, request_id: str, job: Callable[[], None]) -> bool:
        """Run ``job`` in the worker for ``request_id``; refuse it (a failed status with its own id)
        when another request is being worked on."""
        running = self.worker.current_id
        if not self.worker.submit(lambda: self._run(request_id, job), request_id):
            self.fail(request_id, f"busy: {self.get_name()} is working on request {running or '?'!r}; "
                                  f"request {request_id!r} refused (one request at a time)")
            return False
        return True

    def _run(self, request_id: str, job: Callable[[], None]) -> None:
        with self._status_lock:
            self._active = request_id
            self._progress = (0, 0)
            self.status(request_id, self.phase, "started")
        try:
            job()
        except SpecError as exc:
            self.finish(request_id, "failed", f"malformed input: {exc}")
        except ClimbError as exc:  # InfeasibleError: the constraint
            self.finish(request_id, "failed", str(exc))
        finally:
            with self._status_lock:
                if self._active == request_id:  # ended without a last status (shutting down, a bug)
                    self._active = None

    def _job_crashed(self, request_id: str, exc: BaseException) -> None:
        self.finish(request_id, "failed", f"internal error: {type(exc).__name__}: {exc}")


def check_request_strategy(node: StageNode, request_id: str, request_strategy: str | None, stage: str) -> bool:
    """False (and a failed status naming the reason) when the effective strategy is not runnable."""
    from .pipeline import check_strategy

    strategy = request_strategy or node.params.strategy
    try:
        check_strategy(strategy, stage)
    except (SpecError, InfeasibleError) as exc:
        node.fail(request_id, str(exc))
        return False
    return True


def elapsed(t0: float) -> float:
    return round(time.perf_counter() - t0, 3)
