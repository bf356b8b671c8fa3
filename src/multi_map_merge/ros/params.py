"""The node's private parameters, resolved and validated as a pure function (no master, no
rospy): :func:`resolve_params` takes what ``rospy.get_param('~')`` returns and gives the
:class:`MergeConfig` to run with, plus the errors and warnings to log.

A value of the wrong type or out of range is an error naming the parameter and what it
accepts; the node then runs with that parameter's default (a merger that refuses to start takes
a robot team's map away over one typo; the error line says what was used instead). A private
parameter the node does not know is a warning naming the closest known one. m-explore's
(``multirobot_map_merge``) names are read as aliases (:data:`MEXPLORE_ALIASES`); when an alias
and our own name are both set, ours wins, with a warning (our own former names: unless ours is
at its default, :meth:`MergeConfig.former_name_wins`).
"""
from __future__ import annotations

import difflib
import fnmatch
import math
import re
from dataclasses import dataclass, field, fields
from typing import Any, Callable, Dict, List, Mapping, Optional, Tuple

from ..core.config import MergeConfig
from ..core.merger import REF_PARAMETER, REF_PROPOSED, ReferenceChoice


class _Invalid(ValueError):
    pass


# -- converters: value -> value of the field's type, or _Invalid saying what is accepted
def _number(v: Any) -> float:
    if isinstance(v, bool):
        raise _Invalid('a number')
    if isinstance(v, (int, float)):
        x = float(v)
    elif isinstance(v, str):
        try:
            x = float(v.strip())
        except ValueError:
            raise _Invalid('a number') from None
    else:
        raise _Invalid('a number')
    if not math.isfinite(x):
        raise _Invalid('a finite number')
    return x


def _float(lo: Optional[float] = None, hi: Optional[float] = None, lo_open: bool = False
           ) -> Tuple[Callable[[Any], Any], str]:
    rng = _range_text(lo, hi, lo_open, 'a number')

    def conv(v: Any) -> float:
        try:
            x = _number(v)
        except _Invalid:
            raise _Invalid(rng) from None
        if (lo is not None and (x < lo or (lo_open and x == lo))) or (hi is not None and x > hi):
            raise _Invalid(rng)
        return x
    return conv, rng


def _int(lo: int = 0) -> Tuple[Callable[[Any], Any], str]:
    rng = 'an integer >= %d' % lo

    def conv(v: Any) -> int:
        try:
            x = _number(v)
        except _Invalid:
            raise _Invalid(rng) from None
        if not x.is_integer() or x < lo:
            raise _Invalid(rng)
        return int(x)
    return conv, rng


def _range_text(lo, hi, lo_open, what):
    if lo is not None and hi is not None:
        return '%s in %s%g, %g]' % (what, '(' if lo_open else '[', lo, hi)
    if lo is not None:
        return '%s %s %g' % (what, '>' if lo_open else '>=', lo)
    return what


def _bool(v: Any) -> bool:
    if isinstance(v, bool):
        return v
    if isinstance(v, int) and v in (0, 1):
        return bool(v)
    if isinstance(v, str) and v.strip().lower() in ('true', 'false', '1', '0'):
        return v.strip().lower() in ('true', '1')
    raise _Invalid('true or false')


def _string(nonempty: bool) -> Tuple[Callable[[Any], Any], str]:
    what = 'a non-empty string' if nonempty else 'a string'

    def conv(v: Any) -> str:
        if isinstance(v, (dict, list, tuple)) or v is None or isinstance(v, bool):
            raise _Invalid(what)
        s = str(v).strip()
        if nonempty and not s:
            raise _Invalid(what)
        return s
    return conv, what


# ROS graph names (rosgraph.names.is_legal_name, without importing rosgraph): a name element
# is a letter then letters, digits, underscores
_ELEMENT = r'[A-Za-z][A-Za-z0-9_]*'
_RELATIVE_RE = re.compile(r'^%s(/%s)*$' % (_ELEMENT, _ELEMENT))
_NAME_RE = re.compile(r'^[~/]?%s(/%s)*$' % (_ELEMENT, _ELEMENT))
_ELEMENT_RE = re.compile(r'^%s$' % _ELEMENT)


def _text(v: Any, what: str) -> str:
    if isinstance(v, (dict, list, tuple)) or v is None or isinstance(v, bool):
        raise _Invalid(what)
    return str(v).strip()


def _topic_element(v: Any) -> str:
    """~map_topic: discovery looks for topics /<robot>/<map_topic>, <robot> any namespace (nested too)."""
    what = ("one topic name under each robot's namespace, without '/' (discovery looks for "
            "/<robot>/<map_topic>), e.g. map")
    s = _text(v, what)
    if not _ELEMENT_RE.match(s):
        raise _Invalid(what)
    return s


def _relative_topic(v: Any) -> str:
    """~map_updates_topic: '' or a name relative to each robot's namespace."""
    what = "empty or a topic name relative to each robot's namespace (no leading '/'), e.g. map_updates"
    s = _text(v, what)
    if s and not _RELATIVE_RE.match(s):
        raise _Invalid(what)
    return s


def _topic_name(v: Any) -> str:
    """~merged_map_topic: a legal ROS topic name, relative (to the node's namespace) or global."""
    what = 'a legal ROS topic name, e.g. map or /map'
    s = _text(v, what)
    if not _NAME_RE.match(s) or s.startswith('~'):
        raise _Invalid(what)
    return s


def _frame_id(v: Any) -> str:
    what = "a frame id: not empty, no spaces, no leading '/' (tf2 refuses one)"
    s = _text(v, what)
    if not s or s.startswith('/') or any(ch.isspace() for ch in s):
        raise _Invalid(what)
    return s


def _pattern(v: Any) -> str:
    """~robot_namespace_pattern: matched against a robot's whole namespace (``robots/r1`` of
    ``/robots/r1/map``); ``*`` matches ``/`` too, as in fnmatch."""
    what = "a non-empty fnmatch pattern of a robot's namespace, e.g. tb3_* or robots/*"
    s = _text(v, what).strip('/')
    if not s or any(ch.isspace() for ch in s) or '//' in s:
        raise _Invalid(what)
    return s


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


def _robot_name(v: Any) -> str:
    """~reference_robot: '' or a robot namespace (a leading '/' is dropped)."""
    what = "empty or a robot namespace, e.g. tb3_0"
    s = _text(v, what).strip('/')
    if s and not _RELATIVE_RE.match(s):
        raise _Invalid(what)
    return s


def _string_list(v: Any) -> List[str]:
    what = 'a list of robot namespaces (or one string of them separated by spaces), e.g. [tb3_0, tb3_1]'
    if isinstance(v, str):
        names = v.split()
    elif isinstance(v, (list, tuple)) and all(isinstance(x, str) and x.strip() for x in v):
        names = [x.strip() for x in v]
    else:
        raise _Invalid(what)
    names = [n.strip('/') for n in names]
    if not all(_RELATIVE_RE.match(n) for n in names):
        raise _Invalid(what)
    out: List[str] = []
    for n in names:
        if n not in out:
            out.append(n)
    return out


def _poses(v: Any) -> Dict[str, List[float]]:
    what = 'a mapping robot: [x, y, yaw] of finite numbers'
    if not isinstance(v, dict):
        raise _Invalid(what)
    out = {}
    for k, p in v.items():
        if not isinstance(p, (list, tuple)) or len(p) != 3:
            raise _Invalid(what)
        try:
            out[str(k).strip('/')] = [_number(x) for x in p]
        except _Invalid:
            raise _Invalid(what) from None
    return out


def _tolerance(v: Any) -> List[float]:
    what = '[metres, radians], two numbers >= 0'
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        raise _Invalid(what)
    try:
        out = [_number(x) for x in v]
    except _Invalid:
        raise _Invalid(what) from None
    if min(out) < 0:
        raise _Invalid(what)
    return out


_RATE = _float(0.0, None, lo_open=True)
_UNIT = _float(0.0, 1.0)
_PERCENT = _float(0.0, 100.0)

#: every MergeConfig field: (converter, what it accepts); a unit test checks none is missing
RULES: Dict[str, Tuple[Callable[[Any], Any], str]] = {
    'robot_namespace_pattern': (_pattern, "an fnmatch pattern of a robot's namespace"),
    'robots': (_string_list, 'a list of robot namespaces'),
    'map_topic': (_topic_element, 'one topic name under the robot namespace'),
    'map_updates_topic': (_relative_topic, 'a relative topic name'),
    'merged_map_topic': (_topic_name, 'a topic name'),
    'reference_robot': (_robot_name, 'a robot namespace'),
    'merged_map_frame': (_frame_id, 'a frame id'),
    'estimation_rate': _RATE,
    'merge_rate': _RATE,
    'discovery_rate': _RATE,
    'tf_rate': _RATE,
    'free_thresh': _PERCENT,
    'occupied_thresh': _PERCENT,
    'max_cells': _int(1),
    'akaze_threshold': _float(0.0, None, lo_open=True),
    'max_features': _int(0),
    'feature_cells': _int(0),
    'match_candidates': _int(1),
    'match_ratio': _float(0.0, 1.0, lo_open=True),
    'ransac_threshold': _float(0.0, 100.0, lo_open=True),
    'ransac_iterations': _int(1),
    'ransac_hypotheses': _int(1),
    'min_matches': _int(0),
    'min_inliers': _int(0),
    'min_inlier_ratio': _UNIT,
    'few_inliers': _int(0),
    'few_inliers_min_agreement': _UNIT,
    'replace_margin': _float(0.0),
    'refine': (_bool, 'true or false'),
    'min_agreement': _UNIT,
    'min_overlap_cells': _int(0),
    'agreement_tolerance': _int(0),
    'pose_graph': (_bool, 'true or false'),
    'joint_placement': (_bool, 'true or false'),
    'ambiguity_margin': _UNIT,
    'max_position_sigma': _float(0.0, None, lo_open=True),
    'map_drift': _float(0.0),
    'map_drift_yaw': _float(0.0),
    'bend_maps': (_bool, 'true or false'),
    'bend_node_spacing': _float(0.5, 1000.0),
    'stale_map_timeout': _float(0.0),
    'initial_poses': (_poses, 'a mapping robot: [x, y, yaw]'),
    'initial_pose_tolerance': (_tolerance, '[metres, radians]'),
    'trust_initial_poses': (_bool, 'true or false'),
    'known_init_poses': (_bool, 'true or false'),
    'workers': _int(0),
    'state_file': _string(False),
}


def _prefix_pattern(ns: str) -> str:
    return ns.strip('/') + '*'


#: m-explore's parameter name -> (our parameter, conversion of its value or None)
MEXPLORE_ALIASES: Dict[str, Tuple[str, Optional[Callable[[str], str]]]] = {
    'robot_map_topic': ('map_topic', None),
    'robot_map_updates_topic': ('map_updates_topic', None),
    'robot_namespace': ('robot_namespace_pattern', _prefix_pattern),
    'world_frame': ('merged_map_frame', None),
    'merging_rate': ('merge_rate', None),
}
# (merged_map_topic, discovery_rate, estimation_rate, known_init_poses: m-explore's names are ours)

#: our own former names still read, with a warning: old name -> (new name, why)
DEPRECATED: Dict[str, Tuple[str, str]] = {
    'init_pose_params': ('known_init_poses', 'deprecated: it was on by default and read '
                         "ROBOTIS's Gazebo spawn positions as priors; set ~known_init_poses"),
}

#: private parameters read by the libraries the node uses, not by MergeConfig: what they do
LIBRARY_PARAMS: Dict[str, str] = {
    'diagnostic_period': "diagnostic_updater's: seconds between /diagnostics messages (default 1)",
}
#: ... their rules and defaults, checked as ours are (the node hands the library the value checked)
LIBRARY_RULES: Dict[str, Tuple[Tuple[Callable[[Any], Any], str], Any]] = {
    'diagnostic_period': (_RATE, 1.0),
}


def check_library_param(name: str, value: Any) -> Tuple[Any, Optional[str]]:
    """(the value to use, the error to log or None) for a library's parameter (LIBRARY_RULES)."""
    (conv, _), default = LIBRARY_RULES[name]
    try:
        return conv(value), None
    except _Invalid as e:
        return default, '~%s = %r is invalid: must be %s; using the default %r' % (name, value, e, default)

#: m-explore's parameters read but without an equivalent here: why
MEXPLORE_IGNORED: Dict[str, str] = {
    'estimation_confidence': (
        'm-explore\'s estimation_confidence (a threshold on OpenCV stitching\'s match confidence) '
        'has no equivalent here and is ignored: links are accepted by min_inliers, '
        'min_inlier_ratio and the verification on the grids (min_agreement)'),
}


@dataclass
class Resolved:
    config: MergeConfig
    errors: List[str] = field(default_factory=list)
    warnings: List[str] = field(default_factory=list)
    notes: List[str] = field(default_factory=list)   # aliases read: worth an info line
    library: Dict[str, Any] = field(default_factory=dict)   # LIBRARY_RULES' parameters, checked
    library_given: Dict[str, Any] = field(default_factory=dict)   # ... and as given (when given)


def resolve_params(given: Mapping[str, Any]) -> Resolved:
    """``given``: the node's private namespace as a mapping (name -> value)."""
    default = MergeConfig()
    names = [f.name for f in fields(MergeConfig)]
    errors: List[str] = []
    warnings: List[str] = []
    notes: List[str] = []
    raw: Dict[str, Any] = {}
    for name in names:
        if name in given:
            raw[name] = given[name]
    # former names of ours, then m-explore's: each only where our own name is not set (ours
    # former names also where it is at its default, as config/map_merge.yaml sets it)
    aliases = {old: (new, None, 'its former name') for old, new in MergeConfig.RENAMED.items()}
    aliases.update({k: (new, conv, "m-explore's name") for k, (new, conv) in MEXPLORE_ALIASES.items()})
    aliases.update({k: (new, None, 'its deprecated name') for k, (new, _) in DEPRECATED.items()})
    read_as: Dict[str, str] = {}   # our name -> the alias its value was read from
    for alias, (ours, conv, kind) in aliases.items():
        if alias not in given:
            continue
        if ours in given and not (alias in MergeConfig.RENAMED and MergeConfig.former_name_wins(given, alias)):
            warnings.append('~%s (%s for ~%s) ignored: ~%s is set too and wins (%r)'
                            % (alias, kind, ours, ours, given[ours]))
            continue
        value = given[alias]
        if alias in DEPRECATED:
            warnings.append('~%s is %s (read as ~%s: %r)' % (alias, DEPRECATED[alias][1], ours, value))
        if conv is not None and isinstance(value, str):
            value = conv(value)   # (anything else is left as given: an error naming the alias below)
        raw[ours] = value
        read_as[ours] = alias
        if alias not in DEPRECATED:
            notes.append('~%s read as ~%s (%s): %r' % (alias, ours, kind, value))
    for alias, why in MEXPLORE_IGNORED.items():
        if alias in given:
            warnings.append('~%s: %s' % (alias, why))
    kw: Dict[str, Any] = {}
    for name, value in raw.items():
        conv, accepts = RULES[name]
        try:
            kw[name] = conv(value)
        except _Invalid as e:
            shown = '~%s (given as ~%s)' % (name, read_as[name]) if name in read_as else '~%s' % name
            errors.append('%s = %r is invalid: must be %s; using the default %r'
                          % (shown, value, e, getattr(default, name)))
    # cross-parameter checks
    free = kw.get('free_thresh', default.free_thresh)
    occ = kw.get('occupied_thresh', default.occupied_thresh)
    if free >= occ:
        errors.append('~free_thresh (%g) must be below ~occupied_thresh (%g); using the defaults '
                      '%g and %g' % (free, occ, default.free_thresh, default.occupied_thresh))
        kw.pop('free_thresh', None)
        kw.pop('occupied_thresh', None)
    ref = kw.get('reference_robot', default.reference_robot)
    robots = kw.get('robots', default.robots)
    pattern = kw.get('robot_namespace_pattern', default.robot_namespace_pattern)
    if ref and robots and ref not in robots:
        errors.append('~reference_robot %r is not one of ~robots (%s): its map would never be read and '
                      'nothing merged; using the default %r (the first of ~robots by name, %s)'
                      % (ref, ' '.join(robots), default.reference_robot, sorted(robots)[0]))
        kw.pop('reference_robot', None)
    elif ref and not robots and not fnmatch.fnmatchcase(ref, pattern):
        errors.append('~reference_robot %r does not match ~robot_namespace_pattern %r: it would never be '
                      'discovered and nothing merged; using the default %r (chosen by name among the '
                      'robots discovered)' % (ref, pattern, default.reference_robot))
        kw.pop('reference_robot', None)
    library: Dict[str, Any] = {}
    library_given: Dict[str, Any] = {}
    for name, (_, lib_default) in LIBRARY_RULES.items():
        library[name] = lib_default
        if name in given:
            library_given[name] = given[name]
            library[name], error = check_library_param(name, given[name])
            if error:
                errors.append(error)
    known = set(names) | set(aliases) | set(MEXPLORE_IGNORED) | set(LIBRARY_PARAMS)
    for name in sorted(given):
        if name in known:
            continue
        close = difflib.get_close_matches(name, sorted(known), n=1, cutoff=0.6)
        warnings.append('unknown parameter ~%s ignored%s' % (
            name, ': did you mean ~%s?' % close[0] if close else ' (the README lists the parameters)'))
    return Resolved(MergeConfig(**kw), errors, warnings, notes, library, library_given)


def reference_message(choice: ReferenceChoice) -> str:
    """The node's info line saying which robot is the reference (the merged frame is its map
    frame), why, and how to choose it (``~reference_robot``); '' before there is one."""
    ref = choice.robot
    if not ref:
        return ''
    if choice.why == REF_PARAMETER:
        return 'reference robot %s (set by ~reference_robot): the merged frame is its map frame' % ref
    if choice.why == REF_PROPOSED:
        return ('reference robot %s (the first of ~robots by name; set ~reference_robot to choose '
                'another): the merged frame is its map frame' % ref)
    others = ', '.join(choice.with_maps)
    if not choice.fixed:
        return ('reference robot %s for now (the first by name among the robots with a map: %s): the '
                'merged frame is its map frame; a robot of a lower name whose map comes before another '
                'robot is merged with %s takes it over; set ~reference_robot to fix it' % (ref, others, ref))
    return ('reference robot %s, fixed now that another robot is merged with it (it was the first by name '
            'among the robots with a map: %s; a robot whose map comes later does not take the merged '
            'frame over): set ~reference_robot: %s for the same merged frame in every run'
            % (ref, others, ref))
