"""One source of truth for the controller's parameter defaults: the schema's defaults equal
config/nodes/controller.yaml (a node started without --params-file behaves as the YAML says; the
node declares its parameters with the YAML's values, controller_node.node.default_params)."""
from __future__ import annotations

from climb_core.params import describe, flatten
from controller_node.params import ControllerParams, load_controller_params


def test_every_schema_default_equals_the_yaml():
    yaml_values = flatten(load_controller_params())
    code_values = flatten(ControllerParams())
    assert set(yaml_values) == set(describe(ControllerParams))
    differ = {name: (code_values[name], yaml_values[name]) for name in yaml_values
              if code_values[name] != yaml_values[name]}
    assert not differ, f"schema default != config/nodes/controller.yaml: {differ}"


def test_qp_failure_grace_agrees():  # the disagreement issue 16 names (0.0 in the code, 0.2 in the YAML)
    assert ControllerParams().qp.failure_grace_s == load_controller_params().qp.failure_grace_s == 0.2


def test_cross_field_rules_hold_whichever_parser_builds_the_params():
    """The node's on-set validation goes through climb_core.params.parse_params: the collision
    rule (security < influence distance) lives in the dataclass, so it applies there too."""
    import pytest

    from climb_core.errors import SpecError
    from climb_core.params import parse_params

    with pytest.raises(SpecError, match="influence_distance"):
        parse_params({"collision.security_distance": 0.5}, ControllerParams, "controller")
