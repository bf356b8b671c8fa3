"""Every parameter of the merger and of its node, each declared once: name, default, unit, what
it accepts, what it means, its former names and m-explore's names for it. The rest is derived
from these tables: :class:`~multi_map_merge.core.config.MergeConfig` (its fields and defaults),
the one resolver every front end uses (:func:`resolve`: the node, ``merge_maps``,
``evaluate_map``), ``config/map_merge.yaml`` and the README's parameter table
(``python3 -m multi_map_merge.core.parameters --yaml`` / ``--markdown``; ``tools/gen_params.py``
writes both, and a unit test checks the committed files equal its output).

Two tables: :data:`MERGER` holds what the merger itself uses (also offline), :data:`NODE` what
only the ROS node uses (discovery, topics, frames, rates, state file, the diagnostics period).

ROS-free: no rospy. Names are checked as ROS names with regular expressions
(``rosgraph.names.is_legal_name`` without importing rosgraph).
"""
from __future__ import annotations

import argparse
import copy
import difflib
import fnmatch
import json
import math
import re
import sys
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple


class Invalid(ValueError):
    """A value a parameter does not accept; its text says what is accepted."""


class ParameterError(ValueError):
    """Parameters a front end refuses (``merge_maps --config``): every error, one per line."""


#: a parameter's check: (converter: value as given -> value of the field's type, or raises
#: :class:`Invalid` saying what is accepted; what it accepts, in a few words)
Rule = Tuple[Callable[[Any], Any], str]


# -- converters
def _number(v: Any) -> float:
    if isinstance(v, bool):
        raise Invalid('a number')
    if isinstance(v, (int, float)):
        x = float(v)
    elif isinstance(v, str):
        try:
            x = float(v.strip())
        except ValueError:
            raise Invalid('a number') from None
    else:
        raise Invalid('a number')
    if not math.isfinite(x):
        raise Invalid('a finite number')
    return x


def _range_text(lo, hi, lo_open, what):
    if lo is not None and hi is not None:
        return '%s in %s%g, %g]' % (what, '(' if lo_open else '[', lo, hi)
    if lo is not None:
        return '%s %s %g' % (what, '>' if lo_open else '>=', lo)
    return what


def _float(lo: Optional[float] = None, hi: Optional[float] = None, lo_open: bool = False) -> Rule:
    rng = _range_text(lo, hi, lo_open, 'a number')

    def conv(v: Any) -> float:
        try:
            x = _number(v)
        except Invalid:
            raise Invalid(rng) from None
        if (lo is not None and (x < lo or (lo_open and x == lo))) or (hi is not None and x > hi):
            raise Invalid(rng)
        return x
    return conv, rng


def _int(lo: int = 0) -> Rule:
    rng = 'an integer >= %d' % lo

    def conv(v: Any) -> int:
        try:
            x = _number(v)
        except Invalid:
            raise Invalid(rng) from None
        if not x.is_integer() or x < lo:
            raise Invalid(rng)
        return int(x)
    return conv, rng


def _bool(v: Any) -> bool:
    if isinstance(v, bool):
        return v
    if isinstance(v, int) and v in (0, 1):
        return bool(v)
    if isinstance(v, str) and v.strip().lower() in ('true', 'false', '1', '0'):
        return v.strip().lower() in ('true', '1')
    raise Invalid('true or false')


def _string(nonempty: bool) -> Rule:
    what = 'a non-empty string' if nonempty else 'a string'

    def conv(v: Any) -> str:
        if isinstance(v, (dict, list, tuple)) or v is None or isinstance(v, bool):
            raise Invalid(what)
        s = str(v).strip()
        if nonempty and not s:
            raise Invalid(what)
        return s
    return conv, what


# ROS graph names: a name element is a letter then letters, digits, underscores
_ELEMENT = r'[A-Za-z][A-Za-z0-9_]*'
RELATIVE_NAME_RE = re.compile(r'^%s(/%s)*$' % (_ELEMENT, _ELEMENT))
_NAME_RE = re.compile(r'^[~/]?%s(/%s)*$' % (_ELEMENT, _ELEMENT))
_ELEMENT_RE = re.compile(r'^%s$' % _ELEMENT)


def _text(v: Any, what: str) -> str:
    if isinstance(v, (dict, list, tuple)) or v is None or isinstance(v, bool):
        raise Invalid(what)
    return str(v).strip()


def _topic_element(v: Any) -> str:
    """~map_topic: discovery looks for topics /<robot>/<map_topic>, <robot> any namespace (nested too)."""
    what = ("one topic name under each robot's namespace, without '/' (discovery looks for "
            "/<robot>/<map_topic>), e.g. map")
    s = _text(v, what)
    if not _ELEMENT_RE.match(s):
        raise Invalid(what)
    return s


def _relative_topic(v: Any) -> str:
    """~map_updates_topic: '' or a name relative to each robot's namespace."""
    what = "empty or a topic name relative to each robot's namespace (no leading '/'), e.g. map_updates"
    s = _text(v, what)
    if s and not RELATIVE_NAME_RE.match(s):
        raise Invalid(what)
    return s


def _topic_name(v: Any) -> str:
    """~merged_map_topic: a legal ROS topic name, relative (to the node's namespace) or global."""
    what = 'a legal ROS topic name, e.g. map or /map'
    s = _text(v, what)
    if not _NAME_RE.match(s) or s.startswith('~'):
        raise Invalid(what)
    return s


def _frame_id(v: Any) -> str:
    what = "a frame id: not empty, no spaces, no leading '/' (tf2 refuses one)"
    s = _text(v, what)
    if not s or s.startswith('/') or any(ch.isspace() for ch in s):
        raise Invalid(what)
    return s


def _pattern(v: Any) -> str:
    """~robot_namespace_pattern: matched against a robot's whole namespace (``robots/r1`` of
    ``/robots/r1/map``); ``*`` matches ``/`` too, as in fnmatch."""
    what = "a non-empty fnmatch pattern of a robot's namespace, e.g. tb3_* or robots/*"
    s = _text(v, what).strip('/')
    if not s or any(ch.isspace() for ch in s) or '//' in s:
        raise Invalid(what)
    return s


def _robot_name(v: Any) -> str:
    """~reference_robot: '' or a robot namespace (a leading '/' is dropped)."""
    what = "empty or a robot namespace, e.g. tb3_0"
    s = _text(v, what).strip('/')
    if s and not RELATIVE_NAME_RE.match(s):
        raise Invalid(what)
    return s


def _string_list(v: Any) -> List[str]:
    what = 'a list of robot namespaces (or one string of them separated by spaces), e.g. [tb3_0, tb3_1]'
    if isinstance(v, str):
        names = v.split()
    elif isinstance(v, (list, tuple)) and all(isinstance(x, str) and x.strip() for x in v):
        names = [x.strip() for x in v]
    else:
        raise Invalid(what)
    names = [n.strip('/') for n in names]
    if not all(RELATIVE_NAME_RE.match(n) for n in names):
        raise Invalid(what)
    out: List[str] = []
    for n in names:
        if n not in out:
            out.append(n)
    return out


def _poses(v: Any) -> Dict[str, List[float]]:
    what = 'a mapping robot: [x, y, yaw] of finite numbers'
    if not isinstance(v, dict):
        raise Invalid(what)
    out = {}
    for k, p in v.items():
        if not isinstance(p, (list, tuple)) or len(p) != 3:
            raise Invalid(what)
        try:
            out[str(k).strip('/')] = [_number(x) for x in p]
        except Invalid:
            raise Invalid(what) from None
    return out


def _tolerance(v: Any) -> List[float]:
    what = '[metres, radians], two numbers >= 0'
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        raise Invalid(what)
    try:
        out = [_number(x) for x in v]
    except Invalid:
        raise Invalid(what) from None
    if min(out) < 0:
        raise Invalid(what)
    return out


def _prefix_pattern(ns: str) -> str:
    """m-explore's ``robot_namespace`` (a prefix) as our ``robot_namespace_pattern``."""
    return ns.strip('/') + '*'


_RATE = _float(0.0, None, lo_open=True)
_UNIT = _float(0.0, 1.0)
_PERCENT = _float(0.0, 100.0)
_BOOL: Rule = (_bool, 'true or false')
_PATTERN: Rule = (_pattern, "an fnmatch pattern of a robot's namespace")
_ROBOTS: Rule = (_string_list, 'a list of robot namespaces')
_MAP_TOPIC: Rule = (_topic_element, 'one topic name under the robot namespace')
_UPDATES_TOPIC: Rule = (_relative_topic, 'a relative topic name')
_TOPIC_NAME: Rule = (_topic_name, 'a topic name')
_ROBOT_NAME: Rule = (_robot_name, 'a robot namespace')
_FRAME_ID: Rule = (_frame_id, 'a frame id')
_POSES: Rule = (_poses, 'a mapping robot: [x, y, yaw]')
_TOLERANCE: Rule = (_tolerance, '[metres, radians]')


@dataclass(frozen=True)
class Parameter:
    """One parameter: its only declaration.

    ``default`` is the value of the field's type (lists and dicts copied per use); ``unit`` the
    unit of its value ('' for counts, ratios, names, switches); ``meaning`` one line (the YAML
    comment); ``doc`` the README's text (defaults to ``meaning``). ``former``: our own earlier
    names, read as the parameter with an info line (the former one wins when ours is at its
    default, as config/map_merge.yaml sets every parameter); ``deprecated``: (earlier name, why)
    pairs, read with a warning; ``mexplore``: (m-explore's name, conversion of a string value or
    None), read with an info line. ``library``: the library that reads it (not a MergeConfig field)."""
    name: str
    default: Any
    rule: Rule
    unit: str
    meaning: str
    doc: str = ''
    former: Tuple[str, ...] = ()
    deprecated: Tuple[Tuple[str, str], ...] = ()
    mexplore: Tuple[Tuple[str, Optional[Callable[[str], str]]], ...] = ()
    library: str = ''
    section: str = ''

    @property
    def accepts(self) -> str:
        return self.rule[1]

    def convert(self, value: Any) -> Any:
        """``value`` as the field's type, or :class:`Invalid` saying what is accepted."""
        return self.rule[0](value)

    def fresh_default(self) -> Any:
        return copy.deepcopy(self.default)

    @property
    def kind(self) -> str:
        """Its type as the README names it."""
        d = self.default
        if isinstance(d, bool):
            return 'bool'
        if isinstance(d, int):
            return 'int'
        if isinstance(d, float):
            return 'double'
        if isinstance(d, dict):
            return 'dict'
        if isinstance(d, list):
            return 'double list' if d and isinstance(d[0], float) else 'string list'
        return 'string'


def _P(name: str, default: Any, rule: Rule, unit: str, meaning: str, doc: str = '', **kw) -> Parameter:
    return Parameter(name, default, rule, unit, meaning, doc or meaning, **kw)


def _section(title: str, *rows: Parameter) -> Tuple[Parameter, ...]:
    return tuple(Parameter(**dict(r.__dict__, section=title)) for r in rows)


@dataclass(frozen=True)
class Table:
    """Parameters of one owner and the checks across them: each check takes the values read
    (name -> converted value, only those given and valid) and the table's defaults, and returns
    (message, names to reset to their defaults) pairs."""
    name: str
    rows: Tuple[Parameter, ...]
    checks: Tuple[Callable[[Dict[str, Any], Dict[str, Any], str], List[Tuple[str, Tuple[str, ...]]]], ...] = ()

    def __getitem__(self, name: str) -> Parameter:
        for p in self.rows:
            if p.name == name:
                return p
        raise KeyError(name)

    def names(self) -> List[str]:
        return [p.name for p in self.rows]


# The tables' rows: _P(name, default, rule, unit, one-line meaning, README text, former=...,
# deprecated=..., mexplore=..., library=...) by section (the YAML file's and README's order).

NODE_ROWS = (
    _section('which maps',
        _P('robot_namespace_pattern', 'tb3_*', _PATTERN, '',
          'discover /<robot>/map topics whose <robot> (the whole namespace, nested too) matches',
          ("fnmatch pattern of `<robot>` in discovered `/<robot>/map` topics, matched against the robot's "
           'whole namespace (`robots/r1` of `/robots/r1/map`); `*` matches `/` too (`*` finds every robot, '
           '`robots/*` those under `/robots`); a leading or trailing `/` is dropped'),
          mexplore=(('robot_namespace', _prefix_pattern),)),
        _P('robots', [], _ROBOTS, '',
          'robot namespaces listed explicitly (no discovery); [] = discover',
          ('explicit robot namespaces (a list, or one string of names separated by spaces, as '
           "`map_merge.launch`'s arg `robots` gives it; legal ROS names, a leading `/` dropped, repeats "
           'once); empty = discover')),
        _P('map_topic', 'map', _MAP_TOPIC, '',
          'per-robot map topic under its namespace',
          ('per-robot map topic under its namespace: one name, no `/` (discovery looks for topics '
           '`/<robot>/<map_topic>`; `a/b` or `/map` is an error)'),
          mexplore=(('robot_map_topic', None),)),
        _P('map_updates_topic', '', _UPDATES_TOPIC, '',
          'per-robot updates topic; "" = <map_topic>_updates',
          ('per-robot `map_msgs/OccupancyGridUpdate` topic under its namespace (relative: no leading `/`); '
           'empty = `<map_topic>_updates`'),
          mexplore=(('robot_map_updates_topic', None),)),
        _P('merged_map_topic', 'map', _TOPIC_NAME, '',
          'output topic of the merged map (metadata on <it>_metadata)',
          'topic of the merged map (its metadata on `<merged_map_topic>_metadata`); the same as remapping `map`'),
        _P('merged_map_frame', 'map', _FRAME_ID, '',
          "frame of /map and parent of every robot's map frame",
          "frame of the merged map, parent of every robot's map frame (no leading `/`: tf2 refuses one)",
          mexplore=(('world_frame', None),)),
    ),
    _section('rates',
        _P('estimation_rate', 0.5, _RATE, 'Hz',
          'estimation cycles',
          'estimation cycles (a thread of the node, pairs in worker processes: never blocks publishing)'),
        _P('merge_rate', 2.0, _RATE, 'Hz',
          'compositing; the highest rate a changed merged map is published at',
          'compositing, and the highest rate at which a changed merged map is published on `map`',
          mexplore=(('merging_rate', None),)),
        _P('discovery_rate', 0.5, _RATE, 'Hz',
          "looking for new robots' map topics",
          "looking for new robots' map topics"),
        _P('tf_rate', 20.0, _RATE, 'Hz',
          'broadcasting the TF of every merged robot',
          'broadcasting `map -> <robot>/map`'),
    ),
    _section('input health',
        _P('stale_map_timeout', 30.0, _float(0.0), 's',
          'a robot whose last map is older is WARN on /diagnostics (kept merged); 0 = off',
          ('a robot whose map publisher is still there but whose last map (a republished unchanged one '
           "counts) is older than this is WARN on `/diagnostics` (`no map for 42 s`), named in the node's "
           "status and logged once; it stays merged with its last map. Well above gmapping's "
           '`map_update_interval` (2 s here); gmapping publishes a map only after it processed a scan, so a '
           "robot standing still under gmapping's own `temporalUpdate` (-1: only on motion) is reported too "
           "(ROBOTIS's and `config/gmapping_lds02.yaml`'s 0.5 s are not). 0 = off")),
    ),
    _section("priors from m-explore's parameters",
        _P('known_init_poses', False, _BOOL, '',
          ("as m-explore's: a robot missing from initial_poses takes /<robot>/map_merge/init_pose_{x,y,yaw} "
           '(off: ignored)'),
          ('as in m-explore: a robot missing from `~initial_poses` takes `/<robot>/map_merge/init_pose_x`, '
           '`_y`, `_yaw` as its prior (same meaning) when all three are set; off: they are ignored. When the'
           " grids show them to be spawn poses of robots whose maps share one frame (ROBOTIS's Gazebo "
           "set-up: the maps agree at identity, not at the priors' offsets, and each spawn point is free "
           'space of its own map), one warning says so and each such prior becomes `[0, 0, 0]` '
           '(Troubleshooting). Its former name `~init_pose_params` (then on by default) is still read, with '
           'a warning'),
          deprecated=(('init_pose_params', "deprecated: it was on by default and read ROBOTIS's Gazebo spawn "
                                               'positions as priors; set ~known_init_poses'),)),
    ),
    _section('persistence',
        _P('state_file', '', _string(False), '',
          ("the merger's state file: verified links saved on change, reloaded (and verified again) at start;"
           ' "" = none'),
          ("the merger's state file: verified links saved here on change and reloaded at start (verified "
           'again before use); empty = none. Its former name `~transforms_file` is still read'),
          former=('transforms_file',)),
    ),
    _section('read by diagnostic_updater',
        _P('diagnostic_period', 1.0, _RATE, 's',
          "diagnostic_updater's: seconds between /diagnostics messages",
          ('seconds between `/diagnostics` messages (read by `diagnostic_updater`, > 0; checked at start as '
           'ours are, and again when changed while running: a bad value is logged and the last good period '
           'kept)'),
          library='diagnostic_updater'),
    ),
)

MERGER_ROWS = (
    _section('reference',
        _P('reference_robot', '', _ROBOT_NAME, '',
          '"" = first robot by name (robot 1) among those with a map, until another is merged with it',
          ('the reference robot (the merged frame is its map frame); empty = first robot by name (robot 1): '
           "of `~robots` when set; else, while the merge is the reference's map alone, the first by name "
           'among the robots whose map arrived (so tb3_0 is the reference whether its gmapping publishes '
           "first or a little after tb3_1's), fixed for the node's life once another robot is merged with it"
           ' (no transform published with a merge ever jumps; a robot whose map comes only after that does '
           'not take the merged frame over: set this, or `~robots`, for the same merged frame in every run).'
           ' The node logs which robot is the reference and why (an info line `reference robot tb3_0 ...` '
           'when it is chosen, changes, and is fixed). Must be one of `~robots`, or match '
           "`~robot_namespace_pattern` (else an error, and empty is used). `map_merge.launch`'s "
           '`reference_robot` arg (and that of every launch file including it) sets it only when not empty, '
           "so a config YAML's value stays")),
    ),
    _section('grid -> image',
        _P('free_thresh', 19.6, _PERCENT, 'percent',
          '0..free_thresh is free',
          '`0..free_thresh` is free'),
        _P('occupied_thresh', 65.0, _PERCENT, 'percent',
          '>= occupied_thresh is occupied',
          '`>= occupied_thresh` is occupied'),
        _P('max_cells', 25000000, _int(1), 'cells',
          'larger grids are refused (logged)',
          'a grid larger than this is refused (logged)'),
    ),
    _section('features and matching',
        _P('akaze_threshold', 0.0003, _float(0.0, None, lo_open=True), '',
          'AKAZE response threshold; lower finds more features',
          'AKAZE response threshold; lower finds more features'),
        _P('max_features', 2000, _int(0), '',
          'strongest features kept per map; 0 = all',
          'strongest features kept per map; 0 = all'),
        _P('feature_cells', 120000, _int(0), 'cells',
          'larger known areas are described on a coarser image; 0 = never',
          ('known areas larger than this (cells) are described on a coarser image (a pair is matched at the '
           "finer of its two maps' scales); 0 = never")),
        _P('match_candidates', 2, _int(1), '',
          'nearest neighbours kept per feature',
          'nearest neighbours kept per feature'),
        _P('match_ratio', 0.8, _float(0.0, 1.0, lo_open=True), '',
          "Lowe's ratio, used to score the inlier ratio",
          "Lowe's ratio, used only to count the inlier ratio"),
    ),
    _section('RANSAC and reliability',
        _P('ransac_threshold', 3.0, _float(0.0, 100.0, lo_open=True), 'cells',
          'RANSAC inlier distance (also the ICP pairing distance)',
          'RANSAC inlier distance (also the ICP pairing distance), at most 100'),
        _P('ransac_iterations', 15000, _int(1), '',
          'two-point samples; most fail the rigid length test early',
          'two-point RANSAC samples'),
        _P('ransac_hypotheses', 8, _int(1), '',
          'distinct transforms verified per pair',
          'distinct transforms verified per pair'),
        _P('min_matches', 10, _int(0), '',
          'fewer candidate matches: no estimate',
          'fewer candidate matches: no estimate'),
        _P('min_inliers', 10, _int(0), '',
          'fewer RANSAC inliers: rejected',
          'fewer RANSAC inliers: rejected'),
        _P('min_inlier_ratio', 0.0, _UNIT, '',
          'inlier ratio below this: rejected',
          'inlier ratio below this: rejected (also read as `~min_reliability`, its former name)',
          former=('min_reliability',)),
        _P('few_inliers', 21, _int(0), '',
          'a link with fewer RANSAC inliers than this ...',
          'a link with fewer RANSAC inliers than this must also reach `~few_inliers_min_agreement`'),
        _P('few_inliers_min_agreement', 0.96, _UNIT, '',
          '... must verify at least this well (a look-alike place agrees only in the main); 0 = off',
          ('wall agreement a link of fewer than `~few_inliers` inliers needs (a look-alike place agrees only'
           ' in the main); 0 = off')),
        _P('replace_margin', 0.02, _float(0.0), '',
          'a new transform must beat the kept one by this',
          "a new link or placement must beat the kept one's inlier ratio by this"),
    ),
    _section('verification on the grids',
        _P('refine', True, _BOOL, '',
          'ICP of wall cells after RANSAC',
          'ICP of wall cells after RANSAC'),
        _P('min_agreement', 0.8, _UNIT, '',
          'wall agreement in the overlap, 0..1',
          'verification: wall agreement in the overlap, 0..1'),
        _P('min_overlap_cells', 400, _int(0), 'cells',
          'known in both maps',
          'verification: cells known in both maps'),
        _P('agreement_tolerance', 2, _int(0), 'cells',
          'a wall may be off by this and still agree',
          'cells a wall may be off and still agree'),
        _P('pose_graph', True, _BOOL, '',
          'place robots by all verified links at once (cycles averaged)',
          ('place the robots by all their verified links at once (an SE(2) pose graph: the errors of a chain'
           ' are averaged over every cycle); off: along the chain of most reliable links only')),
        _P('joint_placement', True, _BOOL, '',
          "then refine every placement against every placed map it overlaps (within 0.5 m, 9 deg of the links' pose)",
          ('then refine every placement against every placed map it overlaps at once (its wall cells against'
           " the others' walls, within 0.5 m and 9 degrees of the pose its links gave, kept only where the "
           'maps agree at least as well): a gmapping map bends, and its links fit only near where the robots'
           " met; off: the links' placements as they are")),
        _P('ambiguity_margin', 0.1, _UNIT, '',
          'a second, distinct placement verifying within this agreement of the best: left unmerged; 0 = off',
          ('a pair whose second, clearly different placement (over 0.5 m or 5 degrees away) also passes '
           'every gate with an agreement within this of the best is left unmerged as ambiguous (reason on '
           '/diagnostics); 0 = off')),
        _P('max_position_sigma', 0.1, _float(0.0, None, lo_open=True), 'm',
          "a robot whose placement's 2-sigma position (worst direction) exceeds this is reported weakly pinned",
          ("a merged robot whose placement's 2-sigma position (along its worst direction, from its links' "
           "covariances, with the maps' drift, propagated along its chain or combined by the pose graph) "
           'exceeds this is reported *weakly pinned* (status, `merge_maps`); it stays merged')),
        _P('map_drift', 0.02, _float(0.0), 'm/m',
          ("how far a SLAM map's walls sit off at a distance from its origin (the robot's start), 1 sigma; 0"
           ' = maps that do not drift'),
          ("how far a SLAM map's walls sit off (1 sigma, each axis) at a distance from its map frame's "
           "origin (the robot's start), as gmapping's do; added to every placement's covariance for each "
           "map's stretch between its origin and the overlap a link was fitted on (calibrated on real "
           'gmapping maps: docs/measurements.md). 0 for maps that do not drift (cut from one ground truth)')),
        _P('map_drift_yaw', 0.4, _float(0.0), 'deg/sqrt(m)',
          'how far they sit turned, 1 sigma (a turn read off the walls is added)',
          ("how far they sit turned (1 sigma); where a map's walls show how far it turned between its origin "
           'and an overlap (their direction modulo 90 degrees, `core/drift.py`), that turn is added')),
        _P('bend_maps', False, _BOOL, '',
          ('the merged map only: bend each placed map, smoothly and as far as map_drift allows, onto the '
           'walls of the maps it overlaps (TF stays rigid)'),
          ('the merged map only: bend each placed map, smoothly and no more than `~map_drift` allows, onto '
           'the walls of the maps it overlaps (`core/deform.py`); TF stays the rigid placement. Off: every '
           'map composited rigidly')),
        _P('bend_node_spacing', 2.5, _float(0.5, 1000.0), 'm',
          "between the nodes of a bent map's correction field",
          "between the nodes of a bent map's correction field (0.5-1000)"),
    ),
    _section("prior knowledge (optional): pose of each robot's map frame in one frame common to all priors",
        _P('initial_poses', {}, _POSES, 'm, m, rad',
          'e.g. {tb3_0: [0, 0, 0], tb3_1: [0, 0, 0]}: robots started together, same heading',
          ("optional prior: robot -> `[x, y, yaw]` (metres, radians), the pose of that robot's map frame in "
           'one frame common to all priors (e.g. all `[0, 0, 0]` when the robots started together with one '
           "heading). Only differences count: the merged frame is the reference robot's map frame, and a "
           'link between robots a and b is checked against `prior_a^-1 * prior_b`. Also set and removed '
           'while running, per robot (`/<robot>/map_merge/prior`, `clear_prior`): a pose in the merged frame'
           " is composed with the reference's prior; without one the merged frame becomes the priors' frame "
           '(the reference at `[0, 0, 0]`)')),
        _P('initial_pose_tolerance', [1.0, 0.35], _TOLERANCE, 'm, rad',
          'a link contradicting the priors by more is rejected',
          ('a link contradicting the priors by more is rejected; also the window (at most 1.5 m, 30 degrees)'
           ' where the walls are searched for a link near the priors when no link the features propose fits '
           'them')),
        _P('trust_initial_poses', False, _BOOL, '',
          'place a robot with a prior but no verified link at its prior',
          'place a robot that has a prior but no verified link at its prior (`via: initial_pose`)'),
    ),
    _section('speed',
        _P('workers', 0, _int(0), 'processes',
          'estimation workers; 0 = one per core (small maps inline), 1 = inline',
          ("estimation worker processes (forked at the node's start, sharing its memory); 0 = one per core, "
           'and small problems (maps whose known parts hold under 400,000 cells in all) estimated in the '
           "node's own process; 1 = always in the node's own process; 2 or more = that many, always used")),
        _P('estimation_budget', 5.0, _float(0.0), 's',
          'alignments from features start within this of a cycle\'s start; 0 = no limit',
          ("seconds of an estimation cycle within which its pairs' alignments from features start, in priority "
           'order (pairs that can place a robot not yet placed first, by the overlap they can have); the '
           'others wait for a later cycle, so that a cycle places what it found without waiting for every '
           "pair of a large team. Kept links are tracked on new maps (milliseconds) beyond it. 0 = no limit")),
        _P('refresh_links', True, _BOOL, '',
          'between estimation cycles, track again the kept links whose maps grew most, with their covariance',
          ("spend the time between estimation cycles (until the next is due) on the kept links whose maps grew "
           "most since their covariance was computed: each tracked again on the maps as they are now, with its "
           "covariance, and the robots placed again. A cycle tracks only a few of a robot's links when its map "
           "changes, so the others stand as found on smaller maps; refreshed, placements in a large team are "
           "as accurate as if every pair were aligned anew. Stops once the maps stop growing. false = the "
           "estimation workers idle between cycles")),
        _P('dask_scheduler', '', _string(False), '',
          ("a Dask scheduler's address (e.g. tcp://host:8786) to align the pairs on its workers; "
           '"" = the local workers'),
          ("a Dask scheduler's address (e.g. `tcp://host:8786`): the pairs are aligned on its cluster's workers"
           ' (which need this package, OpenCV and numpy of the same versions on their PYTHONPATH), with the same'
           ' results as here. Needs `python3-distributed` only when set. A cluster that fails (unreachable, '
           'scheduler or all workers lost) is left for the local workers (`~workers`) with one log line, the '
           "cycle's pairs done again here; it is tried again after 60 s. Empty = the local workers only")),
    ),
)


def _thresholds(v: Dict[str, Any], d: Dict[str, Any], p: str) -> List[Tuple[str, str, Tuple[str, ...]]]:
    free = v.get('free_thresh', d['free_thresh'])
    occ = v.get('occupied_thresh', d['occupied_thresh'])
    if free < occ:
        return []
    return [('%sfree_thresh (%g) must be below %soccupied_thresh (%g)' % (p, free, p, occ),
             'using the defaults %g and %g' % (d['free_thresh'], d['occupied_thresh']),
             ('free_thresh', 'occupied_thresh'))]


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


#: what the merger uses (the node and the offline front ends)
MERGER = Table('merger', sum(MERGER_ROWS, ()), (_thresholds,))
#: what only the ROS node uses; ``library`` rows are read by a library the node uses
NODE = Table('node', sum(NODE_ROWS, ()), (_reference_found,))
TABLES: Tuple[Table, ...] = (MERGER, NODE)

#: m-explore's parameters read but without an equivalent here: why
MEXPLORE_IGNORED: Dict[str, str] = {
    'estimation_confidence': (
        'm-explore\'s estimation_confidence (a threshold on OpenCV stitching\'s match confidence) '
        'has no equivalent here and is ignored: links are accepted by min_inliers, '
        'min_inlier_ratio and the verification on the grids (min_agreement)'),
}


def parameters(tables: Sequence[Table] = TABLES) -> List[Parameter]:
    return [p for t in tables for p in t.rows]


def config_parameters() -> List[Parameter]:
    """The parameters that are MergeConfig's fields, in its field order."""
    return [p for p in parameters() if not p.library]


def renamed() -> Dict[str, str]:
    """Our former names: old name -> name."""
    return {old: p.name for p in parameters() for old in p.former}


def former_name_wins(given: Mapping[str, Any], old: str) -> bool:
    """Whether ``given`` (parameters by name) is read by the former name ``old`` of a renamed
    parameter: it is given, and the new name is absent or at its default. config/map_merge.yaml
    lists every parameter at its default, so a launch file that loads it and sets a former name
    means the former name's value."""
    new = renamed()[old]
    default = _by_name()[new].default
    return old in given and (given.get(new) is None or given[new] == default)


def _by_name() -> Dict[str, Parameter]:
    return {p.name: p for p in parameters()}


@dataclass
class Resolution:
    """What :func:`resolve` read: ``values`` (name -> value of every parameter of the tables:
    given and valid, else its default), and the lines to tell the user."""
    values: Dict[str, Any]
    errors: List[str] = field(default_factory=list)
    warnings: List[str] = field(default_factory=list)
    notes: List[str] = field(default_factory=list)   # aliases read: worth an info line


def resolve(given: Mapping[str, Any], tables: Sequence[Table] = TABLES, prefix: str = '~',
            strict: bool = False, checks_of: Optional[Sequence[Table]] = None) -> Resolution:
    """Every parameter of ``tables`` from ``given`` (name -> value, as a YAML file or the
    parameter server holds them): converted and range-checked; m-explore's names and our former
    names read as aliases; a name none of the tables knows reported with the closest known one.

    Not ``strict`` (the node): an invalid value is an error and its default is used, an unknown
    name a warning. ``strict`` (the offline front ends): the same errors, and an unknown name is
    one too; messages do not name a default. Names are shown after ``prefix``. The checks across
    parameters are those of ``checks_of`` (default: ``tables``)."""
    rows = parameters(tables)
    by_name = {p.name: p for p in rows}
    errors: List[str] = []
    warnings: List[str] = []
    notes: List[str] = []
    raw: Dict[str, Any] = {n: given[n] for n in by_name if n in given}
    # former names of ours, then m-explore's, then the deprecated: each only where our own name is
    # not set (our former names also where it is at its default, as config/map_merge.yaml sets it)
    aliases: Dict[str, Tuple[str, Optional[Callable[[str], str]], str, str]] = {}
    for p in rows:
        for old in p.former:
            aliases[old] = (p.name, None, 'its former name', '')
    for p in rows:
        for old, conv in p.mexplore:
            aliases[old] = (p.name, conv, "m-explore's name", '')
    for p in rows:
        for old, why in p.deprecated:
            aliases[old] = (p.name, None, 'its deprecated name', why)
    read_as: Dict[str, str] = {}   # our name -> the alias its value was read from
    for alias, (ours, conv, kind, why) in aliases.items():
        if alias not in given:
            continue
        is_former = kind == 'its former name'
        if ours in given and not (is_former and former_name_wins(given, alias)):
            warnings.append('%s%s (%s for %s%s) ignored: %s%s is set too and wins (%r)'
                            % (prefix, alias, kind, prefix, ours, prefix, ours, given[ours]))
            continue
        value = given[alias]
        if why:
            warnings.append('%s%s is %s (read as %s%s: %r)' % (prefix, alias, why, prefix, ours, value))
        if conv is not None and isinstance(value, str):
            value = conv(value)   # (anything else is left as given: an error naming the alias below)
        raw[ours] = value
        read_as[ours] = alias
        if not why:
            notes.append('%s%s read as %s%s (%s): %r' % (prefix, alias, prefix, ours, kind, value))
    for alias, text in MEXPLORE_IGNORED.items():
        if alias in given:
            warnings.append('%s%s: %s' % (prefix, alias, text))
    kw: Dict[str, Any] = {}
    for name, value in raw.items():
        p = by_name[name]
        try:
            kw[name] = p.convert(value)
        except Invalid as e:
            shown = '%s%s (given as %s%s)' % (prefix, name, prefix, read_as[name]) if name in read_as \
                else prefix + name
            errors.append('%s = %r is invalid: must be %s%s' % (
                shown, value, e, '' if strict else '; using the default %r' % (p.default,)))
    defaults = {p.name: p.fresh_default() for p in rows}
    for t in (tables if checks_of is None else checks_of):
        for check in t.checks:
            for problem, fallback, reset in check(kw, defaults, prefix):
                errors.append(problem if strict else '%s; %s' % (problem, fallback))
                for n in reset:
                    kw.pop(n, None)
    # (every table's names are known, also those of a table not resolved here)
    known = set(by_name) | set(aliases) | set(MEXPLORE_IGNORED) | {p.name for p in parameters()}
    for name in sorted(given):
        if name in known:
            continue
        close = difflib.get_close_matches(name, sorted(known), n=1, cutoff=0.6)
        hint = ': did you mean %s%s?' % (prefix, close[0]) if close else ' (the README lists the parameters)'
        if strict:
            errors.append('unknown parameter %s%s%s' % (prefix, name, hint))
        else:
            warnings.append('unknown parameter %s%s ignored%s' % (prefix, name, hint))
    values = dict(defaults, **kw)
    return Resolution(values, errors, warnings, notes)


def resolve_strictly(given: Mapping[str, Any], what: str = '') -> Resolution:
    """:func:`resolve` for a front end that refuses what it cannot use: raises
    :class:`ParameterError` (every error, one per line, after ``what``) instead of running with
    defaults. Names are shown as a YAML file spells them (no ``~``). Every parameter is read
    and checked (a YAML file for the node is read offline too), but only the merger's checks
    across parameters apply (the node's concern which robots it discovers)."""
    if not isinstance(given, Mapping):
        raise ParameterError('%sparameters must be a mapping name: value, not %s' % (what, type(given).__name__))
    odd = sorted(repr(k) for k in given if not isinstance(k, str))
    if odd:
        raise ParameterError('%sparameter names must be strings, not %s' % (what, ', '.join(odd)))
    res = resolve(given, prefix='', strict=True, checks_of=(MERGER,))
    if res.errors:
        raise ParameterError('\n'.join(what + e for e in res.errors))
    return res


# -- the generated files

def _yaml_value(v: Any) -> str:
    if isinstance(v, str):
        plain = v and re.match(r'^[A-Za-z][A-Za-z0-9_/.-]*$', v) and v.lower() not in (
            'true', 'false', 'yes', 'no', 'on', 'off', 'null', 'y', 'n')
        return v if plain else json.dumps(v)
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, (list, tuple)):
        return '[%s]' % ', '.join(_yaml_value(x) for x in v)
    if isinstance(v, dict):
        return '{%s}' % ', '.join('%s: %s' % (_yaml_value(k), _yaml_value(x)) for k, x in v.items())
    return repr(v)


YAML_HEADER = """\
# multi_map_merge defaults (the README's Parameters table explains each one).
# Loaded into the node's private namespace by launch/map_merge.launch.
# Generated by tools/gen_params.py from src/multi_map_merge/core/parameters.py: edit there.
"""


def yaml_text() -> str:
    """config/map_merge.yaml: every MergeConfig parameter at its default, by section, each with
    its unit and meaning as a comment."""
    out = [YAML_HEADER]
    section = None
    for t in (NODE, MERGER):
        for p in t.rows:
            if p.library:
                continue   # read by a library, with its own default
            if p.section != section:
                section = p.section
                out.append('\n# %s%s\n' % (section, ' (%s only)' % t.name if t is NODE else ''))
            comment = '%s: %s' % (p.unit, p.meaning) if p.unit else p.meaning
            if p.former:
                comment += '; former name: %s' % ', '.join(p.former)
            out.append('%-34s # %s\n' % ('%s: %s' % (p.name, _yaml_value(p.default)), comment))
    return ''.join(out)


README_BEGIN = ('<!-- parameters: generated by tools/gen_params.py from '
                'src/multi_map_merge/core/parameters.py; edit there -->')
README_END = '<!-- /parameters -->'


def _md_default(p: Parameter) -> str:
    v = p.default
    if isinstance(v, str):
        return '`%s`' % (v if v else '""')
    if isinstance(v, (list, dict)):
        return '`%s`' % _yaml_value(v)
    return _yaml_value(v)


def markdown_table() -> str:
    """The README's parameter table, between its markers: every parameter of both tables."""
    out = [README_BEGIN, '', '| name | type | unit | default | meaning |', '| --- | --- | --- | --- | --- |']
    for t in (NODE, MERGER):
        for p in t.rows:
            out.append('| `~%s` | %s | %s | %s | %s |' % (p.name, p.kind, p.unit, _md_default(p), p.doc))
    out += ['', README_END]
    return '\n'.join(out) + '\n'


def replace_readme_block(text: str) -> str:
    """``text`` (the README) with the block between the markers replaced by :func:`markdown_table`."""
    i = text.index(README_BEGIN)
    j = text.index(README_END, i) + len(README_END)
    if text[j:j + 1] == '\n':
        j += 1
    return text[:i] + markdown_table() + text[j:]


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog='python3 -m multi_map_merge.core.parameters',
                                 description='print config/map_merge.yaml or the README\'s parameter table '
                                             'as the parameter tables give them')
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument('--yaml', action='store_true', help='config/map_merge.yaml')
    g.add_argument('--markdown', action='store_true', help="the README's parameter table, with its markers")
    a = ap.parse_args(argv)
    sys.stdout.write(yaml_text() if a.yaml else markdown_table())
    return 0


if __name__ == '__main__':
    sys.exit(main())
