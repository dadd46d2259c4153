"""Node parameters: ROS-params YAML <-> frozen dataclasses, without ROS.

A node's parameters are a frozen dataclass (the *schema*). Every leaf field has a default, a unit
and a description, optionally ``min`` / ``max`` (inclusive) and ``choices``; a field whose type is
another frozen dataclass is a parameter *group*, named with dots like ROS does
(``watchdog.timeout_s``)::

    @dataclass(frozen=True)
    class Watchdog:
        timeout_s: float = param(0.1, unit="s", description="...", min=0.0)

    @dataclass(frozen=True)
    class BridgeParams:
        rate_hz: float = param(200.0, unit="Hz", description="...", min=1.0)
        watchdog: Watchdog = group(Watchdog, "command watchdog")

Files use the ROS 2 layout ``<node_name>: {ros__parameters: {...}}`` (``/node_name``,
``/**/node_name`` and the ``/**`` wildcard are understood as ``ros2 run --params-file`` does;
nested mappings and dotted keys are both accepted). Values are typed as strictly as ROS types
them: ``1`` is an integer and is refused for a float parameter (write ``1.0``). Leaf types:
bool, int, float, str and ``tuple[<one of those>, ...]`` (ROS arrays). Unknown keys are refused
with SpecError naming ``node.param``. The ROS built-ins (``use_sim_time``, ...) are ignored here:
ROS handles them.

Nodes declare their parameters from :func:`flatten` / :func:`describe`, read them back and call
:func:`parse_params` with the flat dict, so the library receives the same frozen dataclass that
tests build with :func:`load_params` from the same YAML file.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import math
import pathlib
import typing
from dataclasses import dataclass
from typing import Any, Mapping, TypeVar

import yaml

from .errors import SpecError

T = TypeVar("T")

#: Parameters every rclpy node has; a params file may set them, ROS handles them.
ROS_BUILTIN_PARAMS = ("use_sim_time", "start_type_description_service", "start_parameter_event_publisher")
ROS_BUILTIN_PREFIXES = ("qos_overrides.",)

_SCALARS: dict[type, str] = {bool: "bool", int: "int", float: "float", str: "str"}


def param(default: Any, *, unit: str, description: str, min: float | None = None, max: float | None = None,
          choices: tuple | None = None) -> Any:
    """A leaf parameter field: ``default`` in ``unit`` ("-" when dimensionless), with a description."""
    metadata = {"unit": unit, "description": description}
    if min is not None:
        metadata["min"] = min
    if max is not None:
        metadata["max"] = max
    if choices is not None:
        metadata["choices"] = tuple(choices)
    if isinstance(default, list):
        default = tuple(default)
    return dataclasses.field(default=default, metadata=metadata)


def group(cls: type, description: str) -> Any:
    """A parameter group field: a nested frozen dataclass with its own parameters."""
    return dataclasses.field(default_factory=cls, metadata={"description": description})


@dataclass(frozen=True)
class ParamInfo:
    """What a node needs to declare one parameter."""

    name: str  # dotted name, e.g. "watchdog.timeout_s"
    type: str  # bool | int | float | str | bool_array | int_array | float_array | str_array
    default: Any  # tuples for arrays
    unit: str
    description: str
    min: float | None = None
    max: float | None = None
    choices: tuple | None = None

    @property
    def is_array(self) -> bool:
        return self.type.endswith("_array")

    @property
    def element_type(self) -> str:
        return self.type[: -len("_array")] if self.is_array else self.type

    def check(self, value: Any, where: str) -> Any:
        """``value`` typed and range-checked; SpecError(where, rule) otherwise. Arrays -> tuples."""
        if self.is_array:
            if isinstance(value, (str, bytes, Mapping)) or not hasattr(value, "__iter__"):
                raise SpecError(where, f"expected a list of {self.element_type}, got {_kind(value)} {value!r}")
            return tuple(self._check_scalar(v, f"{where}[{i}]") for i, v in enumerate(value))
        return self._check_scalar(value, where)

    def _check_scalar(self, value: Any, where: str) -> Any:
        expected = self.element_type
        ok = {"bool": isinstance(value, bool),
              "int": isinstance(value, int) and not isinstance(value, bool),
              "float": isinstance(value, float),
              "str": isinstance(value, str)}[expected]
        if not ok:
            hint = " (write it with a decimal point: ROS parameters are strictly typed)" \
                if expected == "float" and isinstance(value, int) and not isinstance(value, bool) else ""
            raise SpecError(where, f"expected {expected}, got {_kind(value)} {value!r}{hint}")
        if expected == "float" and not math.isfinite(value):
            raise SpecError(where, f"must be finite, got {value}")
        if self.min is not None and value < self.min:
            raise SpecError(where, f"must be >= {self.min} [{self.unit}], got {value}")
        if self.max is not None and value > self.max:
            raise SpecError(where, f"must be <= {self.max} [{self.unit}], got {value}")
        if self.choices is not None and value not in self.choices:
            raise SpecError(where, f"must be one of {', '.join(map(str, self.choices))}; got {value!r}")
        return value


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, Mapping):
        return "mapping"
    return type(value).__name__


def _leaf_type(tp: Any, where: str) -> str | None:
    """'float', 'float_array', ... for a leaf annotation; None for a group."""
    if dataclasses.is_dataclass(tp):
        return None
    if tp in _SCALARS:
        return _SCALARS[tp]
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis and args[0] in _SCALARS:
            return _SCALARS[args[0]] + "_array"
    raise SpecError(where, f"unsupported parameter type {tp!r}; use bool, int, float, str, "
                           "tuple[<scalar>, ...] or a nested frozen dataclass")


@functools.lru_cache(maxsize=None)
def _schema(schema: type) -> tuple[tuple[str, ParamInfo | None, type | None], ...]:
    """(dotted name, info for leaves, group class) for every field, groups before their members."""
    if not (isinstance(schema, type) and dataclasses.is_dataclass(schema)):
        raise SpecError(getattr(schema, "__name__", repr(schema)), "a parameter schema must be a dataclass")
    out: list[tuple[str, ParamInfo | None, type | None]] = []

    def walk(cls: type, prefix: str) -> None:
        if not cls.__dataclass_params__.frozen:  # type: ignore[attr-defined]
            raise SpecError(cls.__name__, "a parameter schema must be a frozen dataclass")
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            name = prefix + f.name
            where = f"{schema.__name__}.{name}"
            tp = hints[f.name]
            kind = _leaf_type(tp, where)
            description = f.metadata.get("description")
            if not isinstance(description, str) or not description.strip():
                raise SpecError(where, "every parameter needs a description (use param() / group())")
            if kind is None:
                if f.default_factory is dataclasses.MISSING:  # type: ignore[misc]
                    raise SpecError(where, "a parameter group needs default_factory (use group())")
                out.append((name, None, tp))
                walk(tp, name + ".")
                continue
            if f.default is dataclasses.MISSING:
                raise SpecError(where, "every parameter needs a default")
            unit = f.metadata.get("unit")
            if not isinstance(unit, str) or not unit:
                raise SpecError(where, "every parameter needs a unit ('-' when dimensionless)")
            info = ParamInfo(name=name, type=kind, default=f.default, unit=unit, description=description,
                             min=f.metadata.get("min"), max=f.metadata.get("max"),
                             choices=f.metadata.get("choices"))
            info.check(f.default, f"{where} (default)")
            out.append((name, info, None))

    walk(schema, "")
    return tuple(out)


def describe(schema: type) -> dict[str, ParamInfo]:
    """Dotted name -> ParamInfo for every leaf parameter of ``schema`` (validates the schema)."""
    return {name: info for name, info, _ in _schema(schema) if info is not None}


def _flatten_mapping(values: Mapping[str, Any], node_name: str, prefix: str = "",
                     out: dict[str, Any] | None = None) -> dict[str, Any]:
    out = {} if out is None else out
    for key, value in values.items():
        if not isinstance(key, str) or not key:
            raise SpecError(f"{node_name}.{prefix}{key}", "parameter names must be non-empty strings")
        name = prefix + key
        if isinstance(value, Mapping):
            _flatten_mapping(value, node_name, name + ".", out)
        elif name in out:
            raise SpecError(f"{node_name}.{name}", "given twice (nested and dotted)")
        else:
            out[name] = value
    return out


def _is_builtin(name: str) -> bool:
    return name in ROS_BUILTIN_PARAMS or name.startswith(ROS_BUILTIN_PREFIXES)


def parse_params(values: Mapping[str, Any], schema: type[T], node_name: str) -> T:
    """The ``ros__parameters`` mapping of one node (nested or dotted keys, or the flat dict a node
    reads back from ROS) -> an instance of ``schema``; missing parameters take their defaults."""
    entries = _schema(schema)
    leaves = {name: info for name, info, _ in entries if info is not None}
    groups = {name for name, info, _ in entries if info is None}
    given: dict[str, Any] = {}
    for name, value in _flatten_mapping(values, node_name).items():
        where = f"{node_name}.{name}"
        if _is_builtin(name):
            continue
        if name in groups:
            members = [n for n in leaves if n.startswith(name + ".")]
            raise SpecError(where, f"is a parameter group; set its members ({', '.join(members)})")
        if name not in leaves:
            raise SpecError(where, "unknown parameter")
        given[name] = leaves[name].check(value, where)
    return _build(schema, "", given)


def _build(cls: type, prefix: str, given: Mapping[str, Any]) -> Any:
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f in dataclasses.fields(cls):
        name = prefix + f.name
        if dataclasses.is_dataclass(hints[f.name]):
            kwargs[f.name] = _build(hints[f.name], name + ".", given)
        elif name in given:
            kwargs[f.name] = given[name]
    return cls(**kwargs)


def _node_keys(node_name: str) -> tuple[str, ...]:
    name = node_name.lstrip("/")
    return (name, "/" + name, "/**/" + name)


def read_params_document(document: Any, source: str = "<parameters>") -> dict[str, dict[str, Any]]:
    """Check a parsed params document has the ROS layout (``node: {ros__parameters: {...}}`` with
    ROS-typed values) and return node key -> flat dotted parameters."""
    if not isinstance(document, Mapping) or not document:
        raise SpecError(source, "must be a mapping of node names to {ros__parameters: {...}}")
    out: dict[str, dict[str, Any]] = {}
    for node, section in document.items():
        if not isinstance(section, Mapping) or set(section) != {"ros__parameters"}:
            raise SpecError(f"{node}", f"{source}: a node section must hold exactly one key, ros__parameters")
        params = section["ros__parameters"]
        if params is None:
            params = {}
        if not isinstance(params, Mapping):
            raise SpecError(f"{node}.ros__parameters", "must be a mapping of parameter names to values")
        flat = _flatten_mapping(params, str(node))
        for name, value in flat.items():
            _check_ros_value(value, f"{node}.{name}")
        out[str(node)] = flat
    return out


def _check_ros_value(value: Any, where: str) -> None:
    if isinstance(value, (bool, int, float, str)):
        return
    if isinstance(value, (list, tuple)):
        kinds = {_kind(v) for v in value}
        if len(kinds) > 1 or not kinds <= {"bool", "int", "float", "str"}:
            raise SpecError(where, f"a ROS array holds one scalar type, got {sorted(kinds)}")
        return
    raise SpecError(where, f"not a ROS parameter value: {_kind(value)} {value!r}")


def load_params(source: str | pathlib.Path | Mapping[str, Any], schema: type[T], node_name: str) -> T:
    """Parameters of ``node_name`` from a ROS params file (path) or an already parsed document.

    Sections for ``/**`` apply first, then the node's own; other nodes' sections are ignored.
    """
    if isinstance(source, Mapping):
        document, where = source, "<parameters>"
    else:
        path = pathlib.Path(source)
        if not path.is_file():
            raise SpecError(node_name, f"parameter file {path} not found")
        try:
            document = yaml.safe_load(path.read_text())
        except yaml.YAMLError as exc:
            raise SpecError(str(path), f"invalid YAML: {exc}") from None
        where = str(path)
    sections = read_params_document(document, where)
    merged: dict[str, Any] = {}
    found = False
    for key in ("/**",) + _node_keys(node_name):
        if key in sections:
            merged.update(sections[key])
            found = found or key != "/**"
    if not found:
        raise SpecError(node_name, f"{where} has no section `{node_name}: ros__parameters`")
    return parse_params(merged, schema, node_name)


def default_params_file(node_name: str) -> pathlib.Path:
    """config/nodes/<node_name>.yaml of the project."""
    from .ros_env import project_root

    return project_root() / "config" / "nodes" / f"{node_name.lstrip('/')}.yaml"


def flatten(instance: Any) -> dict[str, Any]:
    """Dotted name -> value for every leaf of a parameter dataclass instance (arrays as lists, the
    form rclpy's declare_parameter accepts). Declare an empty array with its ParamInfo.type: rclpy
    cannot infer the type of ``[]``."""
    if not dataclasses.is_dataclass(instance) or isinstance(instance, type):
        raise SpecError(type(instance).__name__, "flatten() needs a parameter dataclass instance")
    infos = describe(type(instance))
    out: dict[str, Any] = {}
    for name, info in infos.items():
        value: Any = instance
        for part in name.split("."):
            value = getattr(value, part)
        out[name] = list(value) if info.is_array else value
    return out


def _yaml_scalar(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        text = repr(value)
        # PyYAML (YAML 1.1) reads 1e-05 as a string: keep a decimal point in every float.
        if "." not in text and "inf" not in text and "nan" not in text:
            text = text.replace("e", ".0e") if "e" in text else text + ".0"
        return text
    return json.dumps(value)


def to_yaml(instance: Any, node_name: str) -> str:
    """A ROS params file for ``instance`` (units and descriptions as comments)."""
    infos = describe(type(instance))
    flat = flatten(instance)
    lines = [f"{node_name}:", "  ros__parameters:"]
    open_groups: list[str] = []
    for name, info in infos.items():
        *parents, leaf = name.split(".")
        common = 0
        while common < min(len(parents), len(open_groups)) and parents[common] == open_groups[common]:
            common += 1
        open_groups = open_groups[:common]
        for part in parents[common:]:
            lines.append("    " + "  " * len(open_groups) + f"{part}:")
            open_groups.append(part)
        value = flat[name]
        text = "[" + ", ".join(_yaml_scalar(v) for v in value) + "]" if info.is_array else _yaml_scalar(value)
        lines.append("    " + "  " * len(open_groups) + f"{leaf}: {text}  # [{info.unit}] {info.description}")
    return "\n".join(lines) + "\n"
