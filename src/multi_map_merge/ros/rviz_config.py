"""rviz for a named team: rviz configs cannot take arguments, so ``robots_rviz`` writes one for
the robots it is given, from ``rviz/multi_map_merge.rviz`` as the template, and starts rviz on
it. Per robot it keeps one map display (``<robot> map`` on ``/<robot>/map``, as the template's
first robot display) and one "2D Pose Estimate" tool publishing on
``/<robot>/map_merge/prior`` (the node reads it as that robot's prior, see the README) and one
"2D Nav Goal" tool publishing on ``/<robot>/move_base_simple/goal`` (each robot's move_base runs
in its namespace). The merger's topics follow its name (``--node``, ``/map_merge`` as
``map_merge.launch`` starts it; m-explore's launch file starts it as ``/map_merge/map_merge``):
the markers display on ``<node>/markers``, the merged map display on ``~merged_map_topic``
resolved in the node's namespace (``map`` -> ``/map``, ``/map_merge/map``). Every other part of
the template (TF, the view, the window layout under ``Window Geometry``) is kept as it is.

rviz 1 names a tool by its class alone (``Tool::load`` reads no ``Name``), so every robot's tool
would say "2D Pose Estimate". Where rviz's Python bindings are installed (``python3-rviz`` on
Debian, part of ``ros-noetic-rviz``) rviz is run through them and each of those tools is
renamed ``<robot> prior``, on its toolbar button and in Tool Properties; else the ``rviz``
executable is started on the config (the tools keep rviz's name, in the robots' order, each
showing its topic in Tool Properties)."""
from __future__ import annotations

import copy
import os
import re
import sys
from typing import Dict, List, Optional

import yaml

from ..cli.args import parser

PRIOR_TOPIC = '/%s/map_merge/prior'
GOAL_TOPIC = '/%s/move_base_simple/goal'
_GLOBAL_NAME = re.compile(r'^(/[A-Za-z][A-Za-z0-9_]*)+$')
_ROBOT_MAP = re.compile(r'^/([^/]+)/map$')


def _robot_map_display(d: dict) -> bool:
    return d.get('Class') == 'rviz/Map' and bool(_ROBOT_MAP.match(str(d.get('Topic', ''))))


def _prior_tool(t: dict) -> bool:
    return t.get('Class') == 'rviz/SetInitialPose' and str(t.get('Topic', '')).endswith('/map_merge/prior')


def _goal_tool(t: dict) -> bool:
    return t.get('Class') == 'rviz/SetGoal' and str(t.get('Topic', '')).endswith('/move_base_simple/goal')


def node_topics(node: str, merged_map_topic: str = 'map') -> Dict[str, str]:
    """The merger's topics rviz shows, for the node's global name ``node``: its markers
    (``~markers``) and its merged map (``merged_map_topic``, relative to its namespace unless
    global)."""
    node = '/' + node.strip('/')
    if not _GLOBAL_NAME.match(node):
        raise ValueError('not a valid node name: %s' % node)
    ns = node.rsplit('/', 1)[0]
    merged = merged_map_topic if merged_map_topic.startswith('/') else '%s/%s' % (ns, merged_map_topic)
    if not _GLOBAL_NAME.match(merged):
        raise ValueError('not a valid topic name: %s' % merged_map_topic)
    return {'markers': node + '/markers', 'map': merged}


def robots_rviz_config(template: str, robots: List[str], node: str = '/map_merge',
                       merged_map_topic: str = 'map') -> str:
    """The text of an rviz config for ``robots`` made from the ``template`` config's text, the
    merger's topics those of the node named ``node`` (:func:`node_topics`)."""
    topics = node_topics(node, merged_map_topic)
    names = [r.strip('/') for r in robots if r.strip('/')]
    if not names:
        raise ValueError('no robot names given')
    bad = [r for r in names if not re.fullmatch(r'[A-Za-z_][A-Za-z0-9_/]*', r)]
    if bad:
        raise ValueError('not valid ROS names: %s' % ' '.join(bad))
    cfg = yaml.safe_load(template)
    vm = cfg['Visualization Manager']
    vm['Displays'] = _one_per_robot(vm['Displays'], _robot_map_display, names,
                                    {'Name': '%s map', 'Topic': '/%s/map'},
                                    'a per-robot map display (rviz/Map on /<robot>/map)')
    vm['Tools'] = _one_per_robot(vm['Tools'], _prior_tool, names, {'Topic': PRIOR_TOPIC},
                                 'an rviz/SetInitialPose tool on /<robot>/map_merge/prior')
    if any(_goal_tool(t) for t in vm['Tools']):   # (a template of one's own may have none)
        vm['Tools'] = _one_per_robot(vm['Tools'], _goal_tool, names, {'Topic': GOAL_TOPIC},
                                     'an rviz/SetGoal tool on /<robot>/move_base_simple/goal')
    robot_maps = {'/%s/map' % r for r in names}
    for d in vm['Displays']:
        if d.get('Class') == 'rviz/MarkerArray' and str(d.get('Marker Topic', '')).endswith('/markers'):
            d['Marker Topic'] = topics['markers']
        elif d.get('Class') == 'rviz/Map' and d.get('Topic') not in robot_maps:
            d['Topic'] = topics['map']   # the merged map (every other map display is a robot's)
    return yaml.safe_dump(cfg, sort_keys=False, default_flow_style=False, width=1 << 20)


def _one_per_robot(entries: list, is_robot_entry, names: List[str], fields: dict, what: str) -> list:
    """``entries`` (rviz displays or tools) with the template's per-robot ones replaced by one per
    robot of ``names``, in their place: copies of the first, with each of ``fields`` set to its
    pattern % robot."""
    proto = next((e for e in entries if is_robot_entry(e)), None)
    if proto is None:
        raise ValueError('the template has no %s' % what)
    at = entries.index(proto)
    kept = [e for e in entries if not is_robot_entry(e)]
    mine = []
    for r in names:
        e = copy.deepcopy(proto)
        for k, pattern in fields.items():
            e[k] = pattern % r
        mine.append(e)
    return kept[:at] + mine + kept[at:]


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
    ap = parser('robots_rviz', robots_rviz_main.__doc__)
    ap.add_argument('--robots', required=True, help='robot namespaces, separated by spaces')
    ap.add_argument('--node', default='/map_merge', help='the merger node\'s name, whose ~markers '
                    'and merged map rviz shows (default /map_merge; m-explore\'s launch file: '
                    '/map_merge/map_merge)')
    ap.add_argument('--merged-map-topic', default='map', help='the node\'s ~merged_map_topic '
                    '(default map, in the node\'s namespace)')
    ap.add_argument('--template', default='', help='rviz config to start from (default: the package\'s)')
    ap.add_argument('--output', default='', help='where to write the config (default: '
                    '$ROS_HOME/multi_map_merge_<robots>.rviz)')
    ap.add_argument('--write-only', action='store_true', help='write the config, do not start rviz')
    ap.add_argument('--print-tools', action='store_true', help='start rviz (needs a display and a '
                    'master), print its toolbar\'s tool names, and exit')
    a = ap.parse_args([x for x in argv if ':=' not in x])
    robots = a.robots.split()
    template = a.template or default_template()
    try:
        with open(template) as f:
            text = robots_rviz_config(f.read(), robots, a.node, a.merged_map_topic)
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
    try:
        from rviz import bindings  # noqa: F401
    except ImportError as e:
        if a.print_tools:
            print('robots_rviz: rviz\'s Python bindings are not installed (%s)' % e, file=sys.stderr)
            return 2
        print('robots_rviz: rviz\'s Python bindings are not installed (%s): starting rviz, whose '
              'prior tools are all called "2D Pose Estimate", in the order %s' % (e, ' '.join(robots)))
        sys.stdout.flush()
        os.execvp('rviz', ['rviz', '-d', out] + ros_args)
    return run_rviz(out, robots, a.print_tools)


def run_rviz(config: str, robots: List[str], print_tools: bool = False) -> int:
    """rviz (its VisualizationFrame, through the Python bindings) on ``config``, each robot's
    prior tool renamed ``<robot> prior``. ``print_tools``: print the toolbar's names and quit."""
    from python_qt_binding.QtCore import QTimer
    from python_qt_binding.QtWidgets import QApplication, QToolBar

    from rviz import bindings as rviz
    app = QApplication(sys.argv[:1])
    frame = rviz.VisualizationFrame()
    frame.setSplashPath('')
    frame.initialize(config)
    frame.show()

    def rename(tools, label, tip):
        old = tools[0].getName()
        actions = [act for bar in frame.findChildren(QToolBar) for act in bar.actions() if act.text() == old]
        for robot, tool in zip(robots, tools):
            tool.setName(label % robot)
        if len(actions) == len(robots):     # the toolbar's buttons, in the tools' order
            for robot, act in zip(robots, actions):
                act.setText(label % robot)
                act.setToolTip(tip % (robot, robot))

    def label():
        tm = frame.getManager().getToolManager()
        tools = [tm.getTool(i) for i in range(tm.numTools())]
        for cls, label, tip in (
                ('rviz/SetInitialPose', '%s prior', 'where %s started: its map frame in the merged frame '
                 '(' + PRIOR_TOPIC + ')'),
                ('rviz/SetGoal', '%s goal', 'a goal for %s\'s move_base (' + GOAL_TOPIC + ')')):
            mine = [t for t in tools if t.getClassId() == cls]
            if len(mine) != len(robots):
                if mine or cls == 'rviz/SetInitialPose':
                    print('robots_rviz: %d %s tools for %d robots: names left as they are'
                          % (len(mine), cls, len(robots)), file=sys.stderr)
            else:
                rename(mine, label, tip)
        if print_tools:     # also when nothing was renamed: the caller sees what rviz shows
            names = [act.text() for bar in frame.findChildren(QToolBar) for act in bar.actions() if act.text()]
            print('robots_rviz tools: %s' % ' | '.join(names))
            print('robots_rviz tool properties: %s' % ' | '.join(t.getName() for t in tools))
            sys.stdout.flush()
            app.quit()

    QTimer.singleShot(500, label)
    return app.exec_()
