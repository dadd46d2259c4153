"""Node scaffolding shared by every executable of the graph (imports rclpy: only nodes import it).

- :func:`run_node`: ``main()`` of an executable. Loopback DDS settings, ``rclpy.init`` without
  rclpy's signal handlers, our own SIGINT / SIGTERM handlers (they only set a flag: the spinning
  loop ends at its next turn, then the nodes are destroyed and the context shut down, all in the
  main thread, so no publish of the main thread can race the shutdown), exit code 0 on a signal
  at any moment, 2 with a one-line message when the factory raises ClimbError or a parameter is
  refused, 1 on a bug. A thread still running at the end (a planning job) ends with the process
  (``os._exit`` once everything is torn down: the interpreter's finalization would abort on it).
- :func:`declare_from_schema`: every field of a climb_core.params schema declared with a
  ParameterDescriptor (description with the unit, range, choices, read_only) and an on-set
  callback that validates a change with climb_core.params.parse_params (the YAML loader's parser).
- :func:`guarded`: a subscription / service callback whose exception is logged and reported on
  ``diagnostics`` instead of killing the node.
- :func:`safe_publish`: a publish from another thread that may race the shutdown.
- :class:`Worker`: one long job at a time in a thread.

Functions take the node as an argument, so a LifecycleNode uses them as a Node does. Loops that
spin by themselves (the bridge's lock-step) check :func:`running` at each turn; never call
``executor.spin()`` (rclpy's EventsExecutor.spin() in the Jazzy wheels never runs a callback).

A signal can come while the executable still imports (seconds on a loaded machine): the module
its console script names must be light at the top, and ``main()`` installs the handlers before
the heavy imports::

    def main(args=None) -> int:                     # <pkg>/<module>.py, entry point
        from climb_core.ros_env import install_signal_handlers
        install_signal_handlers()                   # light module: no rclpy, no numpy
        from msgs_py.node_kit import run_node
        from .my_node import MyNode                 # rclpy, numpy, ... only now
        return run_node(MyNode, args, name="my_node")
"""
from __future__ import annotations

import math
import os
import sys
import threading
import traceback
from typing import Any, Callable, Iterable, Mapping, Sequence

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.parameter import Parameter

from climb_core import ros_env as _ros_env
from climb_core.errors import ClimbError, SpecError
from climb_core.params import ParamInfo, describe, flatten, parse_params

from .topics import qos_for

__all__ = ["run_node", "running", "request_stop", "stop_requested", "install_signal_handlers",
           "declare_from_schema", "descriptor_for", "guarded", "diagnose", "set_diagnostics_publisher", "safe_publish", "Worker",
           "SHUTDOWN_ERRORS", "DESERIALIZE_ERRORS", "decode", "make_executor", "apply_cpu_affinity",
           "declare_array"]

#: [s] longest wait of the default loop's spin_once: the delay between a signal and the exit
SPIN_PERIOD_S = 0.1



def _shutdown_errors() -> tuple[type[BaseException], ...]:
    """What a publish or a wait raises once the context or the entity is gone."""
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    return tuple(e for e in (getattr(_rclpy, "InvalidHandle", None), getattr(_rclpy, "RCLError", None))
                 if isinstance(e, type))


SHUTDOWN_ERRORS = _shutdown_errors()


def _deserialize_errors() -> tuple[type[BaseException], ...]:
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    return tuple(e for e in (getattr(_rclpy, "RMWError", None), getattr(_rclpy, "RCLError", None))
                 if isinstance(e, type))


#: what rclpy.serialization.deserialize_message raises on bytes that are not the type's CDR
DESERIALIZE_ERRORS = _deserialize_errors() + (ValueError, TypeError)


def decode(data: bytes, msg_type):
    """``deserialize_message(data, msg_type)``, or ValueError naming the type and the size when
    the bytes are not a message of that type (a raw subscription's guard against garbage)."""
    from rclpy.serialization import deserialize_message

    try:
        return deserialize_message(data, msg_type)
    except DESERIALIZE_ERRORS as err:
        raise ValueError(f"undecodable {msg_type.__name__} ({len(data)} bytes): {err}") from None


# ------------------------------------------------------------------------------------ signals
_STOP = _ros_env.STOP  # one flag per process, set by SIGINT / SIGTERM (climb_core.ros_env)
install_signal_handlers = _ros_env.install_signal_handlers


def request_stop() -> None:
    """End the spinning loop as a signal would (e.g. a node that finished its job)."""
    _STOP.set()


def stop_requested() -> bool:
    return _STOP.is_set()


def running(context=None) -> bool:
    """True until a signal, :func:`request_stop` or the context's shutdown."""
    return not _STOP.is_set() and rclpy.ok(context=context)


# ------------------------------------------------------------------------------ executor, CPUs
def make_executor():
    """rclpy's EventsExecutor (C++ event queue: about half the CPU of SingleThreadedExecutor per
    message, FIELD_NOTES; it doubled the lock-step rate over ROS), else SingleThreadedExecutor.
    Drive it with ``spin_once`` (its ``spin()`` in the Jazzy wheels never runs a callback)."""
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:  # pragma: no cover - rclpy before Jazzy
        from rclpy.executors import SingleThreadedExecutor

        return SingleThreadedExecutor()
    return EventsExecutor()


def apply_cpu_affinity(node) -> set[int] | None:
    """Pin the process to the node's ``cpu_affinity`` parameter (climb_core.ros_env.pin_to_cpus);
    a parameter left unset keeps the inherited CPU set. Call it after the executor exists, so that
    the DDS threads are pinned too."""
    from rclpy.exceptions import ParameterUninitializedException

    try:
        value = node.get_parameter("cpu_affinity").value
    except ParameterUninitializedException:
        return None
    return _ros_env.pin_to_cpus(value, node.get_logger())


# --------------------------------------------------------------------------------- run_node
def _spin_loop(nodes: Sequence[Any], executor, is_running: Callable[[], bool]) -> None:
    while is_running():
        executor.spin_once(timeout_sec=SPIN_PERIOD_S)


def run_node(factory: Callable[[], Any], args: list[str] | None = None, *, executor=None,
             name: str = "node", loop: Callable[[Sequence[Any], Any, Callable[[], bool]], None] | None = None,
             after_add: Callable[[Sequence[Any], Any], None] | None = None) -> int:
    """Run the node(s) ``factory()`` returns (one node or a sequence) until a signal or shutdown.

    ``executor``: an executor, or a callable making one after ``rclpy.init`` (default:
    :func:`make_executor`, driven with spin_once). ``loop(nodes, executor, running)``
    replaces the default loop (``while running(): executor.spin_once(0.1)``); it must return soon
    after ``running()`` turns False. ``after_add(nodes, executor)`` runs once the nodes are in the
    executor (e.g. apply_cpu_affinity). Returns the exit code: 0 after a signal or a normal end, 2
    when rclpy cannot start (malformed --ros-args), the factory (or the loop) raises ClimbError or
    rclpy refuses a parameter (one line on stderr), 1 on any other exception (its traceback on
    stderr: a bug).
    """
    from rclpy.exceptions import ParameterException
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    install_signal_handlers()
    _ros_env.apply_local_dds_env()
    code = 0
    nodes: list[Any] = []
    ex = None
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as err:  # noqa: BLE001 - malformed --ros-args and the like: the user's error
        print(f"{name}: cannot start ROS: {type(err).__name__}: {err}", file=sys.stderr)
        return 0 if _STOP.is_set() else 2
    try:
        if _STOP.is_set():
            return 0
        built = factory()
        nodes = list(built) if isinstance(built, (list, tuple)) else [built]
        if not _STOP.is_set():
            if executor is None:
                ex = make_executor()
            elif callable(executor) and not hasattr(executor, "spin_once"):
                ex = executor()
            else:
                ex = executor
            for node in nodes:
                ex.add_node(node)
            if after_add is not None:
                after_add(nodes, ex)
            (loop or _spin_loop)(nodes, ex, running)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ClimbError, ParameterException) as err:
        if not _STOP.is_set():
            print(f"{name}: {err}", file=sys.stderr)
            code = 2
    except SHUTDOWN_ERRORS as err:  # a publish or a wait racing a shutdown
        if not (_STOP.is_set() or not rclpy.ok()):
            traceback.print_exc()
            code = 1
        del err
    except Exception:  # noqa: BLE001 - a bug: its traceback, exit 1
        if not _STOP.is_set():
            traceback.print_exc()
            code = 1
    finally:
        _STOP.set()  # worker threads and custom loops see the end
        _teardown_with_deadline(nodes, ex, code)
    _exit_if_threads_remain(code)
    return code


#: [s] wall time the teardown (executor shutdown, node destruction, rclpy shutdown) may take after
#: a signal or the end of the loop before the process ends anyway
TEARDOWN_DEADLINE_S = 10.0


def _teardown_with_deadline(nodes: Sequence[Any], executor, code: int) -> None:
    """:func:`_teardown`, bounded: a teardown stuck past TEARDOWN_DEADLINE_S (measured twice on
    contact_search after SIGINT, idle, in make test: not exited after 20-30 s, cause not found)
    ends the process with ``code`` and one line on stderr, so that a signal always stops a node."""
    done = threading.Event()

    def deadline() -> None:
        if not done.wait(TEARDOWN_DEADLINE_S):
            print(f"shutdown: teardown not finished after {TEARDOWN_DEADLINE_S:.0f} s: exiting", file=sys.stderr)
            _flush_and_exit(code)

    guard = threading.Thread(target=deadline, name="teardown_deadline", daemon=True)
    guard.start()
    try:
        _teardown(nodes, executor)
    finally:
        done.set()
        guard.join(1.0)  # gone at once: not a thread left running for _exit_if_threads_remain


def _exit_if_threads_remain(code: int) -> None:
    """A thread still running (a planning Worker in C++ code, an executor's pool thread in a long
    callback) would be unwound by the interpreter's finalization: "FATAL: exception not rethrown",
    abort, exit -6 (measured on guide_path signalled mid-planning), or joined forever. The nodes
    are destroyed and the context is shut down by now: end the process here, streams flushed."""
    others = [t for t in threading.enumerate() if t is not threading.main_thread() and t.is_alive()]
    if others:
        _flush_and_exit(code)


def _flush_and_exit(code: int) -> None:
    """End the process now (no finalization, no thread joined), stdout and stderr flushed."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def _teardown(nodes: Sequence[Any], executor) -> None:
    for step in ([lambda: executor.shutdown(timeout_sec=1.0)] if executor is not None else []) + \
                [(lambda n=n: n.destroy_node()) for n in reversed(nodes)] + [rclpy.try_shutdown]:
        try:
            step()
        except Exception as err:  # noqa: BLE001 - the process ends anyway; say why, no traceback
            print(f"shutdown: {type(err).__name__}: {err}", file=sys.stderr)


# ------------------------------------------------------------------------------- parameters
_INT_MAX = 2 ** 63 - 1
_ROS_TYPES = {"bool": Parameter.Type.BOOL, "int": Parameter.Type.INTEGER, "float": Parameter.Type.DOUBLE,
              "str": Parameter.Type.STRING, "bool_array": Parameter.Type.BOOL_ARRAY,
              "int_array": Parameter.Type.INTEGER_ARRAY, "float_array": Parameter.Type.DOUBLE_ARRAY,
              "str_array": Parameter.Type.STRING_ARRAY}


def descriptor_for(info: ParamInfo, name: str | None = None, read_only: bool = False) -> ParameterDescriptor:
    """The ParameterDescriptor of one schema field: ``"<description> [<unit>]"`` (+ the range and
    choices in words), its ROS type, a FloatingPointRange / IntegerRange for a bounded scalar."""
    text = f"{info.description} [{info.unit}]"
    bounds = []
    if info.min is not None:
        bounds.append(f">= {info.min}")
    if info.max is not None:
        bounds.append(f"<= {info.max}")
    if bounds:
        text += (" each " if info.is_array else " ") + " and ".join(bounds)
    if info.choices is not None:
        text += "; one of " + ", ".join(map(str, info.choices))
    d = ParameterDescriptor(name=name or info.name, type=_ROS_TYPES[info.type].value, description=text,
                            read_only=read_only)
    if info.choices is not None:
        d.additional_constraints = "one of: " + ", ".join(map(str, info.choices))
    lo, hi = info.min, info.max
    if info.choices is not None and info.type in ("int", "float") and info.choices:  # numeric choices bound it too
        lo = min(info.choices) if lo is None else max(lo, min(info.choices))
        hi = max(info.choices) if hi is None else min(hi, max(info.choices))
    if not info.is_array and (lo is not None or hi is not None):
        if info.type == "float":
            d.floating_point_range = [FloatingPointRange(
                from_value=float(lo) if lo is not None else -math.inf,
                to_value=float(hi) if hi is not None else math.inf, step=0.0)]
        elif info.type == "int":
            d.integer_range = [IntegerRange(from_value=int(math.ceil(lo)) if lo is not None else -_INT_MAX,
                                            to_value=int(math.floor(hi)) if hi is not None else _INT_MAX,
                                            step=0)]
    return d


def _current(node, name: str, info: ParamInfo) -> Any:
    from rclpy.exceptions import ParameterUninitializedException

    try:
        return _value(node.get_parameter(name), info)
    except ParameterUninitializedException:  # an empty array declared by its type
        return list(info.default) if info.is_array else info.default


def _value(param: Parameter, info: ParamInfo) -> Any:
    if param.type_ == Parameter.Type.NOT_SET:
        return list(info.default) if info.is_array else info.default
    value = param.value
    return list(value) if info.is_array else value


def declare_array(node, name: str, param_type, descriptor: ParameterDescriptor, value: Sequence = ()) -> None:
    """Declare an array parameter whose default may be empty (rclpy cannot type ``[]``): declared
    by its type, then set to ``value`` unless an override gave it one, then ``read_only`` applied.
    A parameter declared by its type alone stays *uninitialized*, and rclpy's get_parameters
    service then answers no value at all for a request that names it (measured on the bridge's
    ``cpu_affinity``: 53 names asked, 0 values)."""
    from rclpy.exceptions import ParameterUninitializedException

    final = ParameterDescriptor()
    final.name, final.type, final.description = name, param_type.value, descriptor.description
    final.additional_constraints, final.read_only = descriptor.additional_constraints, descriptor.read_only
    writable = ParameterDescriptor(name=name, type=param_type.value, description=descriptor.description)
    node.declare_parameter(name, param_type, writable)
    try:
        node.get_parameter(name)
    except ParameterUninitializedException:
        result = node.set_parameters([Parameter(name, param_type, list(value))])[0]
        if not result.successful:
            raise SpecError(name, f"cannot initialize: {result.reason}")
    node.set_descriptor(name, final)


def declare_from_schema(node, schema_cls: type, defaults: Any = None, *, prefix: str = "",
                        read_only: Iterable[str] | bool = (), node_name: str | None = None,
                        on_change: Callable[[Any], None] | None = None) -> Any:
    """Declare every field of ``schema_cls`` on ``node`` (names ``prefix + field``) and return the
    parsed settings (an instance of ``schema_cls``, overrides from --params-file / -p applied).

    ``defaults``: an instance of the schema or a flat dotted mapping (None: the schema's own
    defaults). ``read_only``: field names (without the prefix) that cannot change at run time, or
    True for all. A later change of these parameters is validated by ``parse_params`` on the whole
    candidate set (cross-field rules included) and refused with the reason; ``on_change(settings)``
    is called with the new settings when a change passes. Raises SpecError when the initial values
    do not parse (the node's start-up error, exit code 2 in :func:`run_node`).
    """
    infos = describe(schema_cls)
    if defaults is None:
        flat_defaults = {n: (list(i.default) if i.is_array else i.default) for n, i in infos.items()}
    elif isinstance(defaults, Mapping):
        flat_defaults = dict(defaults)
    else:
        flat_defaults = flatten(defaults)
    where = node_name or node.get_name()
    frozen = set(infos) if read_only is True else set(read_only or ())
    unknown = frozen - set(infos)
    if unknown:
        raise SpecError(f"{where}.{sorted(unknown)[0]}", "read_only names a field the schema does not have")
    full = {prefix + n: n for n in infos}
    for ros_name, field in full.items():
        info = infos[field]
        value = flat_defaults.get(field, info.default)
        descriptor = descriptor_for(info, ros_name, field in frozen)
        if info.is_array and not value:  # rclpy cannot infer the type of []
            declare_array(node, ros_name, _ROS_TYPES[info.type], descriptor)
        else:
            node.declare_parameter(ros_name, list(value) if info.is_array else value, descriptor)
    current = {field: _current(node, ros_name, infos[field]) for ros_name, field in full.items()}
    settings = parse_params(current, schema_cls, where)

    def on_set(params: list[Parameter]) -> SetParametersResult:
        mine = [p for p in params if p.name in full]
        if not mine:
            return SetParametersResult(successful=True)
        candidate = {field: _current(node, ros_name, infos[field]) for ros_name, field in full.items()}
        for p in mine:
            field = full[p.name]
            if p.type_ == Parameter.Type.NOT_SET:
                return SetParametersResult(successful=False, reason=f"{where}.{p.name}: cannot be unset")
            candidate[field] = _value(p, infos[field])
        try:
            new = parse_params(candidate, schema_cls, where)
        except SpecError as err:
            return SetParametersResult(successful=False, reason=str(err))
        if on_change is not None:
            try:
                on_change(new)
            except ClimbError as err:
                return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)
    return settings


# --------------------------------------------------------------------------- bad input, threads
def set_diagnostics_publisher(node, publisher) -> None:
    """Let :func:`diagnose` / :func:`guarded` use the node's own ``diagnostics`` publisher (it
    must be a plain publisher of diagnostic_msgs/DiagnosticArray; a lifecycle publisher drops
    messages while inactive)."""
    node._node_kit_diagnostics = publisher


def diagnose(node, name: str, message: str, level: int = 2, values: Mapping[str, Any] | None = None) -> bool:
    """Publish one DiagnosticStatus on the node's ``diagnostics`` (a publisher made on first use);
    False when it could not be published (shutting down)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    try:
        pub = getattr(node, "_node_kit_diagnostics", None)
        if pub is None:
            pub = node.create_publisher(DiagnosticArray, "diagnostics", qos_for("diagnostics"))
            set_diagnostics_publisher(node, pub)
        msg = DiagnosticArray()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.status.append(DiagnosticStatus(level=bytes([level]), name=name, message=message[:2000],
                                           hardware_id=node.get_name(),
                                           values=[KeyValue(key=str(k), value=str(v))
                                                   for k, v in (values or {}).items()]))
        return safe_publish(pub, msg)
    except SHUTDOWN_ERRORS:
        return False


def guarded(node, fn: Callable, what: str) -> Callable:
    """``fn`` as a callback that never kills the node: an exception is logged (one line: the
    type, the message, where) and reported on ``diagnostics`` under ``<node>/<what>``; a service
    callback then answers its response with ``success = False`` and ``error`` / ``message`` set
    when the response has those fields."""

    def callback(*args):
        try:
            return fn(*args)
        except Exception as err:  # noqa: BLE001 - the point of the guard
            if _STOP.is_set() or not node.context.ok():  # shutting down: nothing to report
                return args[-1] if len(args) == 2 else None
            tb = traceback.extract_tb(err.__traceback__)
            at = f" at {tb[-1].filename.rsplit('/', 1)[-1]}:{tb[-1].lineno}" if tb else ""
            text = f"{what}: {type(err).__name__}: {err}"
            try:
                node.get_logger().error(text + at)
            except Exception:  # noqa: BLE001 - logging must not raise out of the guard
                pass
            diagnose(node, f"{node.get_name()}/{what}", text, values={"exception": type(err).__name__})
            if len(args) == 2:  # service: (request, response)
                response = args[1]
                if hasattr(response, "success"):
                    response.success = False
                for field in ("error", "message"):
                    if hasattr(response, field) and isinstance(getattr(response, field), str):
                        setattr(response, field, text)
                return response
            return None

    callback.__name__ = getattr(fn, "__name__", what)
    callback.__doc__ = getattr(fn, "__doc__", None)
    return callback


def safe_publish(publisher, msg) -> bool:
    """``publisher.publish(msg)``; False instead of an exception when the publisher or the
    context is gone (a thread racing the shutdown). Other errors propagate."""
    try:
        publisher.publish(msg)
        return True
    except SHUTDOWN_ERRORS:
        if _STOP.is_set() or not rclpy.ok():
            return False
        raise


class Worker:
    """One long job at a time in a daemon thread (planning); the spinning thread stays free.

    ``submit(job, request_id)`` starts ``job()`` and returns True, or returns False at once when a
    job is running (the caller refuses the request with its own id). An exception of the job is
    logged on ``node`` and passed to ``on_error(request_id, exc)`` (never raised in the thread).
    ``stopping`` is True once the process is ending: a job may check it to stop early.
    """

    def __init__(self, node=None, name: str = "worker",
                 on_error: Callable[[str, BaseException], None] | None = None) -> None:
        self.node = node
        self.name = name
        self.on_error = on_error
        self._lock = threading.Lock()
        self._id: str | None = None
        self._thread: threading.Thread | None = None

    @property
    def busy(self) -> bool:
        return self._lock.locked()

    @property
    def current_id(self) -> str | None:
        """The id of the running job, None when idle."""
        return self._id if self.busy else None

    @property
    def stopping(self) -> bool:
        return _STOP.is_set()

    def submit(self, job: Callable[[], Any], request_id: str) -> bool:
        if not self._lock.acquire(blocking=False):
            return False
        self._id = request_id
        self._thread = threading.Thread(target=self._run, args=(job, request_id), name=self.name, daemon=True)
        try:
            self._thread.start()
        except BaseException:
            self._id = None
            self._lock.release()
            raise
        return True

    def _run(self, job: Callable[[], Any], request_id: str) -> None:
        try:
            job()
        except BaseException as err:  # noqa: BLE001 - a job never kills the process
            if not _STOP.is_set():
                try:
                    if self.node is not None:
                        self.node.get_logger().error(f"{self.name} {request_id!r}: {type(err).__name__}: {err}")
                    if self.on_error is not None:
                        self.on_error(request_id, err)
                except Exception:  # noqa: BLE001 - nor does its error report
                    pass
        finally:
            self._id = None
            self._lock.release()

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the running job; True when idle afterwards."""
        thread = self._thread
        if thread is not None:
            thread.join(timeout)
        return not self.busy
