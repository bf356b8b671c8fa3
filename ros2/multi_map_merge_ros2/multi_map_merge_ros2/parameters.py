"""The node's ROS 2 parameters: every row of the ROS 1 node's tables
(:data:`multi_map_merge.node_config.TABLES`: the merger's and the node's), declared with its
description, unit and range, checked by the same resolver
(:func:`multi_map_merge.ros.params.resolve_params`: m-explore's names and our former ones read as
aliases, an invalid value an error line and its default used).

ROS 2's conventions where ROS 1 had none:
- a parameter read only at start is declared ``read_only``: setting it at run time is refused,
  and :data:`RUNTIME` (rates, timeouts) takes effect at once, checked as at start;
- ``initial_poses`` (ROS 1: a mapping) is a YAML string, ROS 2 having no mapping parameters;
- a list with nothing in it is declared as a string list (``robots``), its type not being
  guessable from an empty value.
"""
from __future__ import annotations

import re
import sys
from typing import Any, Dict, List, Mapping, Optional, Tuple

import yaml
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType

from multi_map_merge import node_config
from multi_map_merge.core import parameters as P
from multi_map_merge.ros.params import Resolved, resolve_params

#: the parameters a running node takes on when set (``ros2 param set``): the node's timers and
#: what it reads at every use; every other parameter shapes the merger's state at start
RUNTIME = ('estimation_rate', 'merge_rate', 'discovery_rate', 'tf_rate', 'stale_map_timeout',
           'diagnostic_period')
#: given as YAML text in ROS 2 (no mapping parameters there)
YAML_TEXT = ('initial_poses',)
# the bounds written in a rule's text, e.g. 'a number in (0, 1]', 'a number >= 0', 'an integer >= 1'
_INTERVAL = re.compile(r'in [\[(](?P<lo>[-0-9.e+]+), (?P<hi>[-0-9.e+]+)\]$')
_LOWER = re.compile(r'>=? (?P<lo>[-0-9.e+]+)$')
_INT64_MAX = 2 ** 63 - 1


def _bounds(accepts: str) -> Tuple[Optional[float], Optional[float]]:
    """(lowest, highest) a rule's text allows (an open bound as its closed one: the resolver
    refuses the bound itself with the rule's text); None where it says none."""
    m = _INTERVAL.search(accepts)
    if m:
        return float(m.group('lo')), float(m.group('hi'))
    m = _LOWER.search(accepts)
    return (float(m.group('lo')), None) if m else (None, None)


def ros2_type(p: P.Parameter) -> int:
    """The ParameterType a row is declared with."""
    if p.name in YAML_TEXT:
        return ParameterType.PARAMETER_STRING
    return {'bool': ParameterType.PARAMETER_BOOL, 'int': ParameterType.PARAMETER_INTEGER,
            'double': ParameterType.PARAMETER_DOUBLE, 'string': ParameterType.PARAMETER_STRING,
            'string list': ParameterType.PARAMETER_STRING_ARRAY,
            'double list': ParameterType.PARAMETER_DOUBLE_ARRAY}[p.kind]


def descriptor(p: P.Parameter) -> ParameterDescriptor:
    """A row's ParameterDescriptor: what it means, its unit, what it accepts and its range;
    ``read_only`` unless it is one of :data:`RUNTIME`."""
    kind = ros2_type(p)
    unit = ' [%s]' % p.unit if p.unit else ''
    d = ParameterDescriptor(
        name=p.name, type=kind, description=p.meaning + unit,
        additional_constraints=('YAML text of ' if p.name in YAML_TEXT else '') + p.accepts,
        read_only=p.name not in RUNTIME)
    lo, hi = _bounds(p.accepts)
    if kind == ParameterType.PARAMETER_DOUBLE and lo is not None:
        d.floating_point_range = [FloatingPointRange(
            from_value=lo, to_value=hi if hi is not None else sys.float_info.max, step=0.0)]
    elif kind == ParameterType.PARAMETER_INTEGER and lo is not None:
        d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi) if hi is not None else _INT64_MAX,
                                        step=1)]
    return d


def declared_value(p: P.Parameter, value: Any) -> Any:
    """A resolved value as its declared type holds it (a mapping as YAML text)."""
    if p.name in YAML_TEXT:
        return yaml.safe_dump(value, default_flow_style=True).strip() if value else ''
    if ros2_type(p) == ParameterType.PARAMETER_DOUBLE_ARRAY:
        return [float(v) for v in value]
    if ros2_type(p) == ParameterType.PARAMETER_STRING_ARRAY:
        return [str(v) for v in value]
    return value


def given_value(name: str, value: Any) -> Any:
    """A value as given to ROS 2 (``-p``, a params file), as the resolver reads it: YAML text of a
    mapping parsed (text that is no YAML is left as it is, for the resolver to refuse)."""
    if name in YAML_TEXT and isinstance(value, str):
        if not value.strip():
            return {}
        try:
            return yaml.safe_load(value)
        except yaml.YAMLError:
            return value
    return value


def resolve_overrides(overrides: Mapping[str, Any]) -> Resolved:
    """The node's parameters from the values given to it (name -> value; ROS 2's own, such as
    use_sim_time, left out), as the ROS 1 node resolves its private namespace (names shown
    without ROS 1's ``~``)."""
    given = {n: given_value(n, v) for n, v in overrides.items()}
    given.update(_dotted_mappings(given))
    return resolve_params(given, prefix='')


def _dotted_mappings(given: Dict[str, Any]) -> Dict[str, Any]:
    """A mapping given in a params file (``initial_poses: {tb3_1: [1.0, 2.0, 0.5]}``), which ROS 2
    flattens into ``initial_poses.tb3_1``, gathered back (and its dotted names taken out of
    ``given``); a nested robot namespace's dots read as slashes (``initial_poses.robots.r1``:
    ``robots/r1``). Where the YAML text is given too, the dotted entries are added to it."""
    out: Dict[str, Any] = {}
    for name in YAML_TEXT:
        dotted = sorted(k for k in given if k.startswith(name + '.'))
        if not dotted:
            continue
        base = given.get(name)
        mapping = dict(base) if isinstance(base, dict) else {}
        for k in dotted:
            mapping[k[len(name) + 1:].replace('.', '/')] = given.pop(k)
        out[name] = mapping
    return out


def check_runtime(name: str, value: Any) -> Optional[str]:
    """None when ``value`` may be set for ``name`` at run time; else the reason it is refused."""
    rows = declared()
    if name not in rows:
        return 'unknown parameter %s' % name
    if name not in RUNTIME:
        return ('%s is read at start only (it shapes the merger\'s state): restart the node with it; '
                'these take effect at run time: %s' % (name, ', '.join(RUNTIME)))
    try:
        rows[name].convert(value)
    except P.Invalid as e:
        return '%s = %r is invalid: must be %s' % (name, value, e)
    return None


def workers_from_argv(argv: List[str]) -> int:
    """``workers`` as given on the command line (``--ros-args -p workers:=N``), read before
    ``rclpy.init`` starts threads, so that the worker pool is forked first (as the ROS 1 node,
    :mod:`multi_map_merge.ros.before_init`); 0 (one per core) when not given or invalid (the
    node says why once it runs)."""
    value = None
    for i, a in enumerate(argv[:-1]):
        if a in ('-p', '--param') and argv[i + 1].startswith('workers:='):
            value = argv[i + 1].split(':=', 1)[1]
    if value is None:
        return 0
    try:
        value = yaml.safe_load(value)
    except yaml.YAMLError:
        return 0
    res = resolve_overrides({'workers': value})
    return 0 if res.errors else res.config.workers


def declared(rows: Optional[List[P.Parameter]] = None) -> Dict[str, P.Parameter]:
    """Every row the node declares, by name."""
    return {p.name: p for p in (rows if rows is not None else node_config.parameters())}
