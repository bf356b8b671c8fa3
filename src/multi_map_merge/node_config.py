"""The ROS node's own parameters (either node: ROS 1's ``map_merge_node`` and ROS 2's), declared
once as the core's are (:mod:`multi_map_merge.core.parameters`): which maps it discovers and
subscribes, the merged map's topic, its timers' rates, the input health check and the period of
``/diagnostics``. :data:`TABLES` is every parameter a node reads (the core's table, then this
one); :class:`NodeConfig` is the node's typed configuration, a
:class:`~multi_map_merge.core.config.MergeConfig` (the merger takes it as it is) with these
fields added.

ROS-free, as the core: topic names are checked as ROS names with regular expressions.
"""
from __future__ import annotations

import fnmatch
import re
from dataclasses import dataclass
from typing import Any, ClassVar, Dict, List, Sequence, Tuple

from .core import parameters as _params
from .core.config import MergeConfig
from .core.parameters import (
    MERGER,
    NAME_ELEMENT,
    RATE,
    RELATIVE_NAME_RE,
    Invalid,
    Parameter,
    Rule,
    Table,
    float_rule,
    row,
    section,
    text_of,
)

NAME_RE = re.compile(r'^[~/]?%s(/%s)*$' % (NAME_ELEMENT, NAME_ELEMENT))
ELEMENT_RE = re.compile(r'^%s$' % NAME_ELEMENT)


def _topic_element(v: Any) -> str:
    """~map_topic: discovery looks for topics /<robot>/<map_topic>, <robot> any namespace (nested too)."""
    what = ("one topic name under each robot's namespace, without '/' (discovery looks for "
            "/<robot>/<map_topic>), e.g. map")
    s = text_of(v, what)
    if not ELEMENT_RE.match(s):
        raise Invalid(what)
    return s


def _relative_topic(v: Any) -> str:
    """~map_updates_topic: '' or a name relative to each robot's namespace."""
    what = "empty or a topic name relative to each robot's namespace (no leading '/'), e.g. map_updates"
    s = text_of(v, what)
    if s and not RELATIVE_NAME_RE.match(s):
        raise Invalid(what)
    return s


def _topic_name(v: Any) -> str:
    """~merged_map_topic: a legal ROS topic name, relative (to the node's namespace) or global."""
    what = 'a legal ROS topic name, e.g. map or /map'
    s = text_of(v, what)
    if not NAME_RE.match(s) or s.startswith('~'):
        raise Invalid(what)
    return s


def _pattern(v: Any) -> str:
    """~robot_namespace_pattern: matched against a robot's whole namespace (``robots/r1`` of
    ``/robots/r1/map``); ``*`` matches ``/`` too, as in fnmatch."""
    what = "a non-empty fnmatch pattern of a robot's namespace, e.g. tb3_* or robots/*"
    s = text_of(v, what).strip('/')
    if not s or any(ch.isspace() for ch in s) or '//' in s:
        raise Invalid(what)
    return s


def _prefix_pattern(ns: str) -> str:
    """m-explore's ``robot_namespace`` (a prefix) as our ``robot_namespace_pattern``."""
    return ns.strip('/') + '*'


def _reference_found(v: Dict[str, Any], d: Dict[str, Any], p: str) -> List[Tuple[str, str, Tuple[str, ...]]]:
    """The node reads maps only of ~robots, or of the robots ~robot_namespace_pattern finds."""
    ref = v.get('reference_robot', d['reference_robot'])
    robots = v.get('robots', d['robots'])
    pattern = v.get('robot_namespace_pattern', d['robot_namespace_pattern'])
    if ref and robots and ref not in robots:
        return [('%sreference_robot %r is not one of %srobots (%s): its map would never be read and nothing merged'
                 % (p, ref, p, ' '.join(robots)),
                 'using the default %r (the first of %srobots by name, %s)'
                 % (d['reference_robot'], p, sorted(robots)[0]), ('reference_robot',))]
    if ref and not robots and not fnmatch.fnmatchcase(ref, pattern):
        return [('%sreference_robot %r does not match %srobot_namespace_pattern %r: it would never be '
                 'discovered and nothing merged' % (p, ref, p, pattern),
                 'using the default %r (chosen by name among the robots discovered)' % d['reference_robot'],
                 ('reference_robot',))]
    return []


_PATTERN: Rule = (_pattern, "an fnmatch pattern of a robot's namespace")
_MAP_TOPIC: Rule = (_topic_element, 'one topic name under the robot namespace')
_UPDATES_TOPIC: Rule = (_relative_topic, 'a relative topic name')
_TOPIC_NAME: Rule = (_topic_name, 'a topic name')


# The table's rows, as the core's: row(name, default, rule, unit, meaning, README text, ...) by
# section (the YAML file's and README's order: the node's sections first).
NODE_ROWS = (
    section('which maps',
        row('robot_namespace_pattern', 'tb3_*', _PATTERN, '',
          'discover /<robot>/map topics whose <robot> (the whole namespace, nested too) matches',
          ("fnmatch pattern of `<robot>` in discovered `/<robot>/map` topics, matched against the robot's "
           'whole namespace (`robots/r1` of `/robots/r1/map`); `*` matches `/` too (`*` finds every robot, '
           '`robots/*` those under `/robots`); a leading or trailing `/` is dropped'),
          mexplore=(('robot_namespace', _prefix_pattern),)),
        row('map_topic', 'map', _MAP_TOPIC, '',
          'per-robot map topic under its namespace',
          ('per-robot map topic under its namespace: one name, no `/` (discovery looks for topics '
           '`/<robot>/<map_topic>`; `a/b` or `/map` is an error)'),
          mexplore=(('robot_map_topic', None),)),
        row('map_updates_topic', '', _UPDATES_TOPIC, '',
          'per-robot updates topic; "" = <map_topic>_updates',
          ('per-robot `map_msgs/OccupancyGridUpdate` topic under its namespace (relative: no leading `/`); '
           'empty = `<map_topic>_updates`'),
          mexplore=(('robot_map_updates_topic', None),)),
        row('merged_map_topic', 'map', _TOPIC_NAME, '',
          'output topic of the merged map (metadata on <it>_metadata)',
          'topic of the merged map (its metadata on `<merged_map_topic>_metadata`); the same as remapping `map`'),
    ),
    section('rates',
        row('estimation_rate', 0.5, RATE, 'Hz',
          'estimation cycles',
          'estimation cycles (a thread of the node, pairs in worker processes: never blocks publishing)'),
        row('merge_rate', 2.0, RATE, 'Hz',
          'compositing; the highest rate a changed merged map is published at',
          'compositing, and the highest rate at which a changed merged map is published on `map`',
          mexplore=(('merging_rate', None),)),
        row('discovery_rate', 0.5, RATE, 'Hz',
          "looking for new robots' map topics",
          "looking for new robots' map topics"),
        row('tf_rate', 20.0, RATE, 'Hz',
          'broadcasting the TF of every merged robot',
          'broadcasting `map -> <robot>/map`'),
    ),
    section('input health',
        row('stale_map_timeout', 30.0, float_rule(0.0), 's',
          'a robot whose last map is older is WARN on /diagnostics (kept merged); 0 = off',
          ('a robot whose map publisher is still there but whose last map (a republished unchanged one '
           "counts) is older than this is WARN on `/diagnostics` (`no map for 42 s`), named in the node's "
           "status and logged once; it stays merged with its last map. Well above gmapping's "
           '`map_update_interval` (2 s here); gmapping publishes a map only after it processed a scan, so a '
           "robot standing still under gmapping's own `temporalUpdate` (-1: only on motion) is reported too "
           "(ROBOTIS's and `config/gmapping_lds02.yaml`'s 0.5 s are not). 0 = off")),
    ),
    section('read by diagnostic_updater',
        row('diagnostic_period', 1.0, RATE, 's',
          "diagnostic_updater's: seconds between /diagnostics messages",
          ('seconds between `/diagnostics` messages (read by `diagnostic_updater`, > 0; checked at start as '
           'ours are, and again when changed while running: a bad value is logged and the last good period '
           'kept)'),
          library='diagnostic_updater'),
    ),
)



#: what only the ROS node uses; ``library`` rows are read by a library the node uses
NODE = Table('node', sum(NODE_ROWS, ()), (_reference_found,))
#: every parameter a node reads: the merger's, then its own
TABLES: Tuple[Table, ...] = (MERGER, NODE)


def parameters() -> List[Parameter]:
    """Every parameter a node reads, in the tables' order."""
    return _params.parameters(TABLES)


def config_parameters() -> List[Parameter]:
    """The parameters that are :class:`NodeConfig`'s fields, in its field order."""
    return _params.config_parameters(TABLES)


@dataclass
class NodeConfig(MergeConfig):
    """The node's configuration: the merger's fields (:class:`MergeConfig`), then one per row of
    :data:`NODE` but the libraries', its default the table's (a unit test checks they agree)."""

    #: the tables its fields come from (:meth:`MergeConfig.from_dict` reads them all)
    TABLES: ClassVar[Sequence[Table]] = TABLES

    robot_namespace_pattern: str = 'tb3_*'
    map_topic: str = 'map'
    map_updates_topic: str = ''
    merged_map_topic: str = 'map'
    estimation_rate: float = 0.5   # Hz
    merge_rate: float = 2.0   # Hz
    discovery_rate: float = 0.5   # Hz
    tf_rate: float = 20.0   # Hz
    stale_map_timeout: float = 30.0   # s
