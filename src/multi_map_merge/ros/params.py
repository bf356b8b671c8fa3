"""The node's private parameters, resolved and validated as a pure function (no master, no
rospy): :func:`resolve_params` takes what ``rospy.get_param('~')`` returns and gives the
:class:`~multi_map_merge.node_config.NodeConfig` to run with, plus the errors and warnings to log.

Every parameter is declared once, in :mod:`multi_map_merge.core.parameters` (the merger's table)
or :mod:`multi_map_merge.node_config` (the node's); this module is the node's use of their
resolver. A value of the wrong type or out
of range is an error naming the parameter and what it accepts; the node then runs with that
parameter's default (a merger that refuses to start takes a robot team's map away over one typo;
the error line says what was used instead). A private parameter the node does not know is a
warning naming the closest known one. m-explore's (``multirobot_map_merge``) names are read as
aliases; when an alias and our own name are both set, ours wins, with a warning (our own former
names: unless ours is at its default, :func:`~multi_map_merge.core.parameters.former_name_wins`).
"""
from __future__ import annotations

import fnmatch
from dataclasses import dataclass, field
from typing import Any, Dict, List, Mapping, Optional, Tuple

from .. import node_config
from ..core import parameters as P
from ..node_config import NodeConfig

#: private parameters read by the libraries the node uses (not NodeConfig's), by name
_LIBRARY: Dict[str, P.Parameter] = {p.name: p for p in node_config.parameters() if p.library}


def check_library_param(name: str, value: Any) -> Tuple[Any, Optional[str]]:
    """(the value to use, the error to log or None) for a library's parameter (one of the
    tables' ``library`` rows, e.g. ``diagnostic_period``), checked as the node's own are."""
    (conv, _), default = _LIBRARY[name].rule, _LIBRARY[name].default
    try:
        return conv(value), None
    except P.Invalid as e:
        return default, '~%s = %r is invalid: must be %s; using the default %r' % (name, value, e, default)


def robot_of_map_topic(topic: str, ttype: str, map_topic: str, pattern: str) -> Optional[str]:
    """The robot whose map ``topic`` is, as m-explore's map_merge finds it (``isRobotMapTopic``,
    ``robotNameFromTopic``): an OccupancyGrid topic named ``<map_topic>`` under any namespace,
    the robot being that namespace (``/robots/r1/map`` -> ``robots/r1``); None when the topic is
    no robot's map or its namespace does not match ``pattern`` (fnmatch over the whole namespace;
    m-explore matches its ``robot_namespace`` anywhere in the topic name)."""
    if ttype != 'nav_msgs/OccupancyGrid':
        return None
    ns, _, name = topic.strip('/').rpartition('/')
    if name != map_topic or not ns:
        return None   # /map itself has no robot namespace
    return ns if fnmatch.fnmatchcase(ns, pattern) else None


@dataclass
class Resolved:
    config: NodeConfig
    errors: List[str] = field(default_factory=list)
    warnings: List[str] = field(default_factory=list)
    notes: List[str] = field(default_factory=list)   # aliases read: worth an info line
    library: Dict[str, Any] = field(default_factory=dict)   # the libraries' parameters, checked
    library_given: Dict[str, Any] = field(default_factory=dict)   # ... and as given (when given)


def resolve_params(given: Mapping[str, Any], prefix: str = '~') -> Resolved:
    """``given``: the node's private namespace as a mapping (name -> value); names are shown
    after ``prefix`` (ROS 2's node: none)."""
    res = P.resolve(given, node_config.TABLES, prefix=prefix)
    config = NodeConfig(**{p.name: res.values[p.name] for p in node_config.config_parameters()})
    library = {name: res.values[name] for name in _LIBRARY}
    library_given = {name: given[name] for name in _LIBRARY if name in given}
    return Resolved(config, res.errors, res.warnings, res.notes, library, library_given)
