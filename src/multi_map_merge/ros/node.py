"""The merger node: discovers robots' maps, feeds them to :class:`MapMerger`, publishes the
merged map, the TF of every placed robot and /diagnostics. See the README's ROS API.

The node discovers, subscribes, converts, calls the merger and publishes; what the merger
decides (placements, priors and their frames, the reference robot) is in ``core/``. The ROS glue
around it has modules of its own: the prior topics and parameters (:mod:`prior_inputs`), the
publishers of the placements (:mod:`placement_outputs`), the log and /diagnostics of the robots'
and the node's state (:mod:`health`, :mod:`updater`), the watch on the set-up
(:mod:`setup_watch`) and what is read before ``rospy.init_node`` (:mod:`before_init`)."""
from __future__ import annotations

import logging
import sys
import threading
import time
from typing import Dict, List, Optional

import rospy
from nav_msgs.msg import MapMetaData
from nav_msgs.srv import GetMap, GetMapResponse
from std_srvs.srv import Trigger, TriggerResponse

from ..core.grid import same_grid
from ..core.merger import MapMerger
from ..core.state import StateFile
from ..core.workers import start_pool
from ..node_config import NodeConfig
from .before_init import NODE_NAME, workers_before_init
from .convert import NumpyGrid, NumpyGridUpdate, grid_from_msg, grid_to_msg, metadata
from .health import NodeHealth
from .map_input import Log, MapInput
from .params import resolve_params, robot_of_map_topic
from .placement_outputs import PlacementOutputs
from .prior_inputs import PriorInputs
from .setup_watch import SetupWatch

# s: refreshing links stops this long before the next estimation cycle is due (a batch of
# tracks under way finishes past its budget)
REFRESH_MARGIN = 0.1

__all__ = ['MergeNode', 'NODE_NAME', 'load_config', 'load_params', 'run_merge_node', 'workers_before_init']


class _ToRosout(logging.Handler):
    """The core's and the runtime's log lines (Python ``logging``, e.g. a Dask cluster left for
    the local workers: ``runtime/cluster.py``) on /rosout and the screen: rospy's logging
    configuration gives loggers other than its own only the node's log file."""

    def emit(self, record: logging.LogRecord) -> None:
        log = (rospy.logerr if record.levelno >= logging.ERROR else
               rospy.logwarn if record.levelno >= logging.WARNING else rospy.loginfo)
        log('%s', record.getMessage())


def log_to_rosout() -> None:
    """The package's Python log lines (warnings and above) to /rosout, not only to the log file."""
    logger = logging.getLogger(__name__.split('.')[0])
    if not any(isinstance(h, _ToRosout) for h in logger.handlers):
        logger.addHandler(_ToRosout(logging.WARNING))
        logger.propagate = False    # (rospy's own lines reach the log file through rosout)


def load_config() -> NodeConfig:
    return load_params().config


def load_params():
    """Every parameter of the node, read once from the private namespace and validated
    (:func:`resolve_params`): an invalid value is logged as an error naming the parameter and
    what it accepts, and its default is used; an unknown name gets a warning naming the closest
    known one; m-explore's names are read as aliases. Every parameter, its default and what it
    accepts are declared in the tables of :mod:`multi_map_merge.core.parameters` and
    :mod:`multi_map_merge.node_config` (NodeConfig and config/map_merge.yaml are made from
    them). Returns the :class:`Resolved` (its ``config`` is the node's)."""
    try:
        given = rospy.get_param('~', {})
    except KeyError:
        given = {}
    res = resolve_params(given if isinstance(given, dict) else {})
    for line in res.errors:
        rospy.logerr('multi_map_merge: %s', line)
    for line in res.warnings:
        rospy.logwarn('multi_map_merge: %s', line)
    for line in res.notes:
        rospy.loginfo('multi_map_merge: %s', line)
    return res


class MergeNode:
    """Thin ROS shell around :class:`MapMerger`.

    Subscribes ``/<robot>/<map_topic>`` for every discovered (or listed) robot, runs estimation
    in a worker thread at ``estimation_rate``, composites in another, publishes ``/map``
    (latched) when the merged map changed (checked at ``merge_rate``), broadcasts
    ``merged_map_frame -> <robot>/map`` at ``tf_rate`` (and, with its covariance, on
    ``/<robot>/map_merge/pose`` when it changes), and publishes its own and every robot's
    state on ``/diagnostics`` (``diagnostic_updater``).
    """

    def __init__(self, config: NodeConfig, diagnostic_period: float = 1.0, given_period=1.0):
        self.cfg = config
        # the reference robot: ~reference_robot, else the first of ~robots by name, else the first
        # by name among the robots with a map until another is merged with it (the merger's rule)
        self.merger = MapMerger(config)
        self._subs: Dict[str, list] = {}
        # the robots' maps in: refused ones logged once per reason, each in a frame of its own
        self._input = MapInput(self.merger, config.merged_map_frame, config.max_cells,
                               Log(lambda line: rospy.logerr('multi_map_merge: %s', line),
                                   lambda line: rospy.logwarn('multi_map_merge: %s', line),
                                   lambda line: rospy.loginfo('multi_map_merge: %s', line)))
        self._lock = threading.Lock()
        self._map_pub = rospy.Publisher(config.merged_map_topic, NumpyGrid, queue_size=1, latch=True)
        self._meta_pub = rospy.Publisher(config.merged_map_topic + '_metadata', MapMetaData,
                                         queue_size=1, latch=True)
        # the placements as TF, /<robot>/map_merge/pose and rviz markers
        self._placements = PlacementOutputs(self.merger, config)
        # vanished and stale robots in the log, and /diagnostics
        self._health = NodeHealth(self.merger, config, diagnostic_period, given_period)
        rospy.Service('~reset', Trigger, self._reset)
        # gmapping's service, under gmapping's (relative) name, beside the `map` topic
        rospy.Service('dynamic_map', GetMap, self._get_map)
        self._state = StateFile(config.state_file, self.merger) if config.state_file else None
        if self._state is not None:
            try:
                n = self._state.restore()
                rospy.loginfo('multi_map_merge: %d saved links read from %s; each is verified again '
                              'before use', n, config.state_file)
            except ValueError as e:
                rospy.logerr('multi_map_merge: %s (starting without its saved links)', e)
        self._priors = PriorInputs(self.merger, config)
        self._input.log_reference()
        for r in config.robots:
            self._subscribe(r.strip('/'))
        self._ready = None   # the latest merged grid, composited off the publishing path
        self._sent = None    # (grid, placements) of the last /map sent
        SetupWatch(self.merger, config)
        self._discover(None)
        rospy.Timer(rospy.Duration(1.0 / config.discovery_rate), self._discover)
        rospy.Timer(rospy.Duration(1.0 / config.merge_rate), self._publish_map)
        self._placements.start()
        self._health.start()
        self._worker = threading.Thread(target=self._estimation_loop, name='estimation', daemon=True)
        self._worker.start()
        self._compositor = threading.Thread(target=self._compositing_loop, name='compositing', daemon=True)
        self._compositor.start()
        rospy.loginfo('multi_map_merge: merging %s maps matching %s; reference %s; merged frame %s',
                      '/<robot>/' + config.map_topic,
                      config.robots or config.robot_namespace_pattern,
                      self.merger.reference or '(the first by name among the robots with a map, until '
                      'another robot is merged with it)', config.merged_map_frame)

    # -- inputs
    def _discover(self, _event) -> None:
        with self._lock:
            map_subs = {robot: subs[0] for robot, subs in self._subs.items()}
        self._health.watch(map_subs, self._input.latest)
        if self.cfg.robots:
            return
        try:
            topics = rospy.get_published_topics()
        except Exception as e:  # master gone for a moment: try again next time
            rospy.logwarn_throttle(30, 'multi_map_merge: topic discovery failed: %s' % e)
            return
        found = []
        for topic, ttype in topics:
            if topic == self._map_pub.resolved_name:
                continue   # our own merged map (~merged_map_topic set to /<robot>/<map_topic>)
            robot = robot_of_map_topic(topic, ttype, self.cfg.map_topic, self.cfg.robot_namespace_pattern)
            if robot:
                found.append(robot)
        for robot in found:
            self._subscribe(robot)

    def _subscribe(self, robot: str) -> None:
        with self._lock:
            if robot in self._subs:
                return
            topic = '/%s/%s' % (robot, self.cfg.map_topic)
            updates = '/%s/%s' % (robot, self.cfg.map_updates_topic or self.cfg.map_topic + '_updates')
            self._subs[robot] = [
                rospy.Subscriber(topic, NumpyGrid, self._on_map, callback_args=robot,
                                 queue_size=1, buff_size=2 ** 26),
                rospy.Subscriber(updates, NumpyGridUpdate, self._on_update,
                                 callback_args=robot, queue_size=10, buff_size=2 ** 24)]
        rospy.loginfo('multi_map_merge: robot %s found, subscribed to %s', robot, topic)
        self._priors.add_robot(robot)

    def _on_map(self, msg, robot: str) -> None:
        self._input.on_map(robot, lambda: grid_from_msg(msg, self.cfg.max_cells))

    def _on_update(self, msg, robot: str) -> None:
        self._input.on_update(robot, msg.x, msg.y, msg.width, msg.height, msg.data)

    # -- estimation, off the publishing path
    def _estimation_loop(self) -> None:
        period = 1.0 / self.cfg.estimation_rate
        while not rospy.is_shutdown():
            t0 = time.monotonic()
            error = None
            try:
                self._priors.check_spawn_poses()
                for event in self.merger.estimate():
                    rospy.loginfo('multi_map_merge: %s', event)
                self._input.log_reference()
            except Exception as e:  # a bad cycle must not end estimation for good
                rospy.logerr('multi_map_merge: estimation failed: %r', e)
                error = e
            seconds = time.monotonic() - t0
            self._health.estimated(seconds, error)
            if error is None:
                self._refresh(t0 + period - REFRESH_MARGIN - time.monotonic())
            self._persist()
            end = t0 + max(period, seconds)
            while not rospy.is_shutdown() and time.monotonic() < end:
                time.sleep(min(0.1, end - time.monotonic() + 1e-3))

    def _refresh(self, budget: float) -> None:
        """The time left until the next estimation cycle spent refreshing the stalest links
        (``~refresh_links``, :meth:`MapMerger.refresh`)."""
        if budget <= 0:
            return
        try:
            for event in self.merger.refresh(budget):
                rospy.loginfo('multi_map_merge: %s', event)
        except Exception as e:  # as a bad cycle: estimation goes on
            rospy.logerr('multi_map_merge: refreshing links failed: %r', e)

    def _persist(self) -> None:
        if self._state is None:
            return
        try:
            self._state.save()
        except OSError as e:
            rospy.logerr_throttle(60, 'multi_map_merge: cannot save %s: %s' % (self.cfg.state_file, e))

    # -- outputs
    def _compositing_loop(self) -> None:
        """Warp and composite in a thread of its own, so that a map that takes long to warp
        never delays the /map timer: the timer publishes whatever grid is ready."""
        period = 1.0 / self.cfg.merge_rate
        while not rospy.is_shutdown():
            t0 = time.monotonic()
            try:
                grid = self.merger.compose()
                if grid is not None:
                    self._ready = grid
            except Exception as e:
                rospy.logerr_throttle(10, 'multi_map_merge: compositing failed: %r' % e)
            time.sleep(max(0.01, period / 2.0 - (time.monotonic() - t0)))

    def _publish_map(self, _event) -> None:
        """Publish the merged map (latched) when it changed since the last one sent: its cells,
        its geometry, or a robot's placement. An unchanged merge sends nothing: the latched
        topic already holds it for every subscriber, late ones included, and resending a whole
        grid at ``merge_rate`` would load every remote subscriber's link for no news."""
        grid = self._ready
        if grid is None:
            return
        sent = self._sent
        if sent is not None and grid is sent[0]:
            return   # compose() returns the very same grid while nothing moved or changed
        placed = {r: pl.T.tobytes() for r, pl in self.merger.placements().items()}
        if sent is not None and placed == sent[1] and same_grid(grid, sent[0]):
            self._sent = (grid, placed)   # recomposed, but to the same cells
            return
        now = rospy.Time.now()
        self._map_pub.publish(grid_to_msg(grid, now, self.cfg.merged_map_frame))
        self._meta_pub.publish(metadata(grid, now))
        self._sent = (grid, placed)

    def _get_map(self, _req) -> GetMapResponse:
        """The merged map as /map has it now (gmapping's ``dynamic_map``); an error before
        the reference robot's first map arrived."""
        grid = self._ready
        if grid is None:
            raise rospy.ServiceException('no merged map yet (no map of the reference robot received)')
        msg = grid_to_msg(grid, rospy.Time.now(), self.cfg.merged_map_frame)
        msg.data = msg.data.tolist()   # the service's response is a plain (not numpy) message
        return GetMapResponse(map=msg)

    def _reset(self, _req) -> TriggerResponse:
        self.merger.reset()
        rospy.logwarn('multi_map_merge: all transforms forgotten (reset service)')
        return TriggerResponse(True, 'all transforms forgotten')


def run_merge_node(argv: Optional[List[str]] = None) -> None:
    """``map_merge_node [ROS remappings]``: the live merger. It discovers the robots' maps
    (/<robot>/map matching ~robot_namespace_pattern, or the robots of ~robots), places every robot's
    map in the reference robot's frame and publishes the merged /map (~merged_map_topic), the TF
    map -> <robot>/map of every merged robot, /diagnostics and rviz markers. It is configured by
    ROS parameters, not options: the private parameters (~estimation_rate, ~reference_robot,
    ~initial_poses, ...; m-explore's names are read too) and its topics, services and TF are
    listed in the README's tables (config/map_merge.yaml holds the defaults, and
    `roslaunch multi_map_merge map_merge.launch` loads it). Usually started by a launch file:

        roslaunch multi_map_merge map_merge.launch [robots:="tb3_0 tb3_1"] [reference_robot:=tb3_0]
        rosrun multi_map_merge map_merge_node _estimation_rate:=0.5 __name:=map_merge"""
    from ..cli.args import parser
    args = rospy.myargv(sys.argv if argv is None else argv)[1:]
    # before the workers fork and rospy starts: --help starts nothing
    parser('map_merge_node', run_merge_node.__doc__).parse_args(args)
    # the estimation workers forked before rospy starts its threads: they share the node's
    # memory (core/workers.py)
    start_pool(workers_before_init())
    rospy.init_node(NODE_NAME)
    log_to_rosout()
    res = load_params()
    MergeNode(res.config, res.library['diagnostic_period'], res.library_given.get('diagnostic_period', 1.0))
    rospy.spin()
