"""rviz for a named team: rviz configs cannot take arguments, so ``robots_rviz`` writes one for
the robots it is given, from ``rviz/multi_map_merge.rviz`` as the template, and starts rviz on
it. Per robot it keeps one map display (``<robot> map`` on ``/<robot>/map``, as the template's
first robot display) and one "2D Pose Estimate" tool publishing on
``/<robot>/map_merge/prior`` (the node reads it as that robot's prior, see the README). Every
other part of the template (the merged map, TF, the view, the window layout under ``Window
Geometry``) is kept as it is."""
from __future__ import annotations

import argparse
import copy
import os
import re
import sys
from typing import List, Optional

import yaml

PRIOR_TOPIC = '/%s/map_merge/prior'
_ROBOT_MAP = re.compile(r'^/([^/]+)/map$')


def _robot_map_display(d: dict) -> bool:
    return d.get('Class') == 'rviz/Map' and bool(_ROBOT_MAP.match(str(d.get('Topic', ''))))


def _prior_tool(t: dict) -> bool:
    return t.get('Class') == 'rviz/SetInitialPose' and str(t.get('Topic', '')).endswith('/map_merge/prior')


def robots_rviz_config(template: str, robots: List[str]) -> str:
    """The text of an rviz config for ``robots`` made from the ``template`` config's text."""
    names = [r.strip('/') for r in robots if r.strip('/')]
    if not names:
        raise ValueError('no robot names given')
    bad = [r for r in names if not re.fullmatch(r'[A-Za-z_][A-Za-z0-9_/]*', r)]
    if bad:
        raise ValueError('not valid ROS names: %s' % ' '.join(bad))
    cfg = yaml.safe_load(template)
    vm = cfg['Visualization Manager']
    displays = vm['Displays']
    proto = next((d for d in displays if _robot_map_display(d)), None)
    if proto is None:
        raise ValueError('the template has no per-robot map display (rviz/Map on /<robot>/map)')
    at = displays.index(proto)
    kept = [d for d in displays if not _robot_map_display(d)]
    mine = []
    for r in names:
        d = copy.deepcopy(proto)
        d['Name'] = '%s map' % r
        d['Topic'] = '/%s/map' % r
        mine.append(d)
    vm['Displays'] = kept[:at] + mine + kept[at:]
    tools = vm['Tools']
    proto_tool = next((t for t in tools if _prior_tool(t)), None)
    if proto_tool is None:
        raise ValueError('the template has no rviz/SetInitialPose tool on /<robot>/map_merge/prior')
    at = tools.index(proto_tool)
    others = [t for t in tools if not _prior_tool(t)]
    priors = []
    for r in names:
        t = copy.deepcopy(proto_tool)
        t['Topic'] = PRIOR_TOPIC % r
        priors.append(t)
    vm['Tools'] = others[:at] + priors + others[at:]
    return yaml.safe_dump(cfg, sort_keys=False, default_flow_style=False, width=1 << 20)


def default_template() -> str:
    import rospkg
    return os.path.join(rospkg.RosPack().get_path('multi_map_merge'), 'rviz', 'multi_map_merge.rviz')


def robots_rviz_main(argv: Optional[List[str]] = None) -> int:
    """``robots_rviz --robots "alpha beta" [--template T.rviz] [--output O.rviz] [--write-only]``:
    write the rviz config for these robots and start rviz on it (ROS remappings such as
    ``__name:=rviz`` from roslaunch are passed on to rviz)."""
    if argv is None:
        argv = sys.argv[1:]
    ros_args = [a for a in argv if ':=' in a]
    ap = argparse.ArgumentParser(prog='robots_rviz', description=robots_rviz_main.__doc__.split('\n')[0])
    ap.add_argument('--robots', required=True, help='robot namespaces, separated by spaces')
    ap.add_argument('--template', default='', help='rviz config to start from (default: the package\'s)')
    ap.add_argument('--output', default='', help='where to write the config (default: '
                    '$ROS_HOME/multi_map_merge_<robots>.rviz)')
    ap.add_argument('--write-only', action='store_true', help='write the config, do not start rviz')
    a = ap.parse_args([x for x in argv if ':=' not in x])
    robots = a.robots.split()
    template = a.template or default_template()
    try:
        with open(template) as f:
            text = robots_rviz_config(f.read(), robots)
    except (OSError, ValueError, KeyError, yaml.YAMLError) as e:
        print('robots_rviz: %s: %s' % (template, e), file=sys.stderr)
        return 2
    out = a.output
    if not out:
        import rospkg
        home = rospkg.get_ros_home()
        os.makedirs(home, exist_ok=True)
        out = os.path.join(home, 'multi_map_merge_%s.rviz' % '_'.join(r.replace('/', '_') for r in robots))
    with open(out, 'w') as f:
        f.write(text)
    print('robots_rviz: %s written for %s' % (out, ' '.join(robots)))
    if a.write_only:
        return 0
    sys.stdout.flush()
    os.execvp('rviz', ['rviz', '-d', out] + ros_args)
    return 0   # not reached
