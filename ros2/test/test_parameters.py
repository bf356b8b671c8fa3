"""The ROS 2 parameters (no graph): the core's tables declared with their types, ranges and
read-only flags; values given as ROS 2 gives them (-p, a params file) resolved as the ROS 1 node
resolves its private namespace; what may change at run time."""
from __future__ import annotations

import pytest

pytest.importorskip('rcl_interfaces', reason='no ROS 2 messages: run through `make test-ros2`')

from rcl_interfaces.msg import ParameterType  # noqa: E402

from multi_map_merge import node_config  # noqa: E402
from multi_map_merge.core import parameters as P  # noqa: E402
from multi_map_merge_ros2 import parameters as params  # noqa: E402


def test_every_row_is_declared_with_its_type_range_and_meaning():
    for p in node_config.parameters():
        d = params.descriptor(p)
        assert d.description.startswith(p.meaning) and d.additional_constraints.endswith(p.accepts)
        assert d.read_only == (p.name not in params.RUNTIME)
        # the declared value of the default has the declared type (rclpy refuses it otherwise)
        value = params.declared_value(p, p.fresh_default())
        assert {ParameterType.PARAMETER_BOOL: bool, ParameterType.PARAMETER_INTEGER: int,
                ParameterType.PARAMETER_DOUBLE: float, ParameterType.PARAMETER_STRING: str,
                ParameterType.PARAMETER_STRING_ARRAY: list,
                ParameterType.PARAMETER_DOUBLE_ARRAY: list}[d.type] is type(value), p.name
    unit = params.descriptor(P.MERGER['min_agreement'])
    assert (unit.floating_point_range[0].from_value, unit.floating_point_range[0].to_value) == (0.0, 1.0)
    count = params.descriptor(P.MERGER['match_candidates'])
    assert count.integer_range[0].from_value == 1
    assert params.descriptor(node_config.NODE['tf_rate']).description.endswith('[Hz]')


def test_values_given_as_ros2_gives_them_resolve_as_in_ros1():
    res = params.resolve_overrides({'merge_rate': 'abc', 'robot_namespace': 'tb3', 'estimation_rate': 1,
                                    'initial_poses': "{tb3_1: [1, 2, 0.5]}", 'min_agreement': 0.7})
    assert res.config.merge_rate == 2.0 and any('merge_rate' in e for e in res.errors)
    assert res.config.estimation_rate == 1.0
    assert res.config.robot_namespace_pattern == 'tb3*'   # m-explore's name read as an alias
    assert res.config.initial_poses == {'tb3_1': [1.0, 2.0, 0.5]}
    assert res.config.min_agreement == 0.7
    # a params file's mapping, flattened by ROS 2, gathered back; a nested namespace's dots as slashes
    flat = params.resolve_overrides({'initial_poses.tb3_2': [0.5, 0.0, 0.1],
                                     'initial_poses.robots.r1': [1.0, 1.0, 0.0]})
    assert flat.config.initial_poses == {'tb3_2': [0.5, 0.0, 0.1], 'robots/r1': [1.0, 1.0, 0.0]}
    assert not flat.errors and not flat.warnings
    unknown = params.resolve_overrides({'merge_rte': 3.0})
    assert any('did you mean merge_rate' in w for w in unknown.warnings)


def test_run_time_changes_are_checked_or_refused_with_the_reason():
    assert params.check_runtime('tf_rate', 10.0) is None
    assert 'must be a number > 0' in params.check_runtime('merge_rate', 0.0)
    assert 'read at start only' in params.check_runtime('min_agreement', 0.5)
    assert params.workers_from_argv(['x', '--ros-args', '-p', 'workers:=3']) == 3
    assert params.workers_from_argv(['x', '--ros-args', '-p', 'workers:=-2']) == 0
    assert params.workers_from_argv(['x']) == 0
