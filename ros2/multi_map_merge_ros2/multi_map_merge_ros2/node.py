"""The ROS 2 merger node: the ROS 1 node's (:mod:`multi_map_merge.ros.node`) topics, TF,
parameters, services, diagnostics and priors over rclpy, every decision left to the same core
(:class:`~multi_map_merge.core.merger.MapMerger`).

ROS 2's conventions: the robots' maps are subscribed and the merged map published
transient-local (reliable, depth 1), as map servers and SLAM nodes publish theirs; a robot whose
map publisher is volatile is subscribed volatile (a transient-local subscription would not match
it); the clock is the node's (``use_sim_time``); parameters are declared (:mod:`.parameters`).
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Dict, List, Optional

import rclpy
from geometry_msgs.msg import PoseWithCovarianceStamped
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import MapMetaData, OccupancyGrid
from nav_msgs.srv import GetMap
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Empty
from std_srvs.srv import Trigger

from multi_map_merge import node_config
from multi_map_merge.core.grid import Grid, same_grid
from multi_map_merge.core.merger import MapMerger
from multi_map_merge.core.priors import PriorOfReference, pose_of
from multi_map_merge.core.state import StateFile
from multi_map_merge.ros.map_input import Log, MapInput
from multi_map_merge.ros.params import robot_of_map_topic

from . import parameters as params
from .convert import grid_from_msg, grid_to_msg, metadata
from .outputs import LATCHED, NodeHealth, PlacementOutputs

NODE_NAME = 'map_merge'
# s: refreshing links stops this long before the next estimation cycle is due (as ROS 1's node)
REFRESH_MARGIN = 0.1
VOLATILE = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
# the parameters rclpy itself declares, not ours
_ROS2_OWN = ('use_sim_time', 'start_type_description_service')


class _ToNodeLog(logging.Handler):
    """The core's and the runtime's Python log lines (warnings and above) on the node's log."""

    def __init__(self, logger):
        super().__init__(logging.WARNING)
        self._logger = logger

    def emit(self, record: logging.LogRecord) -> None:
        (self._logger.error if record.levelno >= logging.ERROR else self._logger.warning)(record.getMessage())


class MergeNode(Node):
    """Thin ROS 2 shell around :class:`MapMerger` (see the module docstring and the README's
    ROS 2 table)."""

    def __init__(self, **node_kw):
        super().__init__(NODE_NAME, **node_kw)
        log = self.get_logger()
        given = {n: p.value for n, p in self._parameter_overrides.items() if n not in _ROS2_OWN}
        res = params.resolve_overrides(given)
        for line in res.errors:
            log.error(line)
        for line in res.warnings:
            log.warning(line)
        for line in res.notes:
            log.info(line)
        self.cfg = cfg = res.config
        self._diagnostic_period = float(res.library['diagnostic_period'])
        values = dict(res.library, **{p.name: getattr(cfg, p.name) for p in node_config.config_parameters()})
        for p in node_config.parameters():
            # ignore_override: a value given was resolved above (an invalid one logged and its default
            # used); rclpy would raise on it instead
            self.declare_parameter(p.name, params.declared_value(p, values[p.name]), params.descriptor(p),
                                   ignore_override=True)
        if cfg.known_init_poses:
            log.warning('known_init_poses: ROS 2 has no other nodes\' /<robot>/map_merge/init_pose_* parameters '
                        'to read; give the poses in initial_poses (or on /<robot>/map_merge/prior)')
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        core_log = logging.getLogger('multi_map_merge')
        core_log.addHandler(_ToNodeLog(log))
        core_log.propagate = False

        self.merger = MapMerger(cfg)
        self._subs: Dict[str, list] = {}
        self._map_topics: Dict[str, str] = {}
        # the robots' maps in, as the ROS 1 node takes them (multi_map_merge.ros.map_input)
        self._input = MapInput(self.merger, cfg.merged_map_frame, cfg.max_cells,
                               Log(log.error, log.warning, log.info))
        self._lock = threading.Lock()
        self._map_pub = self.create_publisher(OccupancyGrid, cfg.merged_map_topic, LATCHED)
        self._meta_pub = self.create_publisher(MapMetaData, cfg.merged_map_topic + '_metadata', LATCHED)
        self._placements = PlacementOutputs(self, self.merger, cfg)
        self._health = NodeHealth(self, self.merger, cfg, self.count_publishers)
        self.create_service(Trigger, '~/reset', self._reset)
        self.create_service(GetMap, 'dynamic_map', self._get_map)
        self._state = StateFile(cfg.state_file, self.merger) if cfg.state_file else None
        if self._state is not None:
            try:
                n = self._state.restore()
                log.info('%d saved links read from %s; each is verified again before use' % (n, cfg.state_file))
            except ValueError as e:
                log.error('%s (starting without its saved links)' % e)
        self._input.log_reference()
        for r in cfg.robots:
            self._subscribe(r.strip('/'))
        self._ready: Optional[Grid] = None   # the latest merged grid, composited off the publishing path
        self._sent = None                    # (grid, placements) of the last merged map sent
        self._rate_timers: Dict[str, object] = {}
        self._start_timers()
        self._running = True
        self._discover()
        self._threads = [threading.Thread(target=self._estimation_loop, name='estimation', daemon=True),
                         threading.Thread(target=self._compositing_loop, name='compositing', daemon=True)]
        for t in self._threads:
            t.start()
        log.info('merging %s maps matching %s; reference %s; merged frame %s'
                 % ('/<robot>/' + cfg.map_topic, cfg.robots or cfg.robot_namespace_pattern,
                    self.merger.reference or '(the first by name among the robots with a map, until another '
                    'robot is merged with it)', cfg.merged_map_frame))

    # -- parameters at run time
    def _start_timers(self) -> None:
        """(Re)create the timers, each at its rate (a rate set at run time takes effect here)."""
        for t in self._rate_timers.values():
            self.destroy_timer(t)
        c = self.cfg
        self._rate_timers = {
            'discovery': self.create_timer(1.0 / c.discovery_rate, self._discover),
            'map': self.create_timer(1.0 / c.merge_rate, self._publish_map),
            'poses': self.create_timer(1.0 / c.merge_rate, self._placements.publish_poses),
            'tf': self.create_timer(1.0 / c.tf_rate, self._placements.publish_tf),
            'diagnostics': self.create_timer(self._diagnostic_period, self._health.publish)}

    def _check_parameters(self, changed: List[rclpy.Parameter]) -> SetParametersResult:
        """Refuse, with the reason, what cannot be set at run time (see :mod:`.parameters`)."""
        for p in changed:
            if p.name in _ROS2_OWN:
                continue
            reason = params.check_runtime(p.name, p.value)
            if reason:
                self.get_logger().warning('parameter refused: %s' % reason)
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, changed: List[rclpy.Parameter]) -> None:
        """Take on the run-time parameters just set (checked by :meth:`_check_parameters`)."""
        ours = [p for p in changed if p.name in params.RUNTIME]
        if not ours:
            return
        for p in ours:
            value = params.declared()[p.name].convert(p.value)
            if p.name == 'diagnostic_period':
                self._diagnostic_period = value
            else:
                setattr(self.cfg, p.name, value)
            self.get_logger().info('parameter %s set to %r: in effect now' % (p.name, value))
        self._start_timers()

    # -- inputs
    def _discover(self) -> None:
        with self._lock:
            topics = dict(self._map_topics)
        self._health.watch(topics, self._input.latest)
        if self.cfg.robots:
            return
        own = self._map_pub.topic_name
        for topic, types in self.get_topic_names_and_types():
            if topic == own:
                continue   # our own merged map (merged_map_topic set to /<robot>/<map_topic>)
            for ttype in types:
                robot = robot_of_map_topic(topic, ttype.replace('/msg/', '/'), self.cfg.map_topic,
                                           self.cfg.robot_namespace_pattern)
                if robot:
                    self._subscribe(robot)

    def _map_qos(self, topic: str) -> QoSProfile:
        """Transient-local, unless a publisher of ``topic`` is volatile (it would not match)."""
        for info in self.get_publishers_info_by_topic(topic):
            if info.qos_profile.durability == DurabilityPolicy.VOLATILE:
                self.get_logger().info('%s is published volatile (not as map servers do): subscribing volatile, '
                                       'its next map is the first this node gets' % topic)
                return VOLATILE
        return LATCHED

    def _subscribe(self, robot: str) -> None:
        with self._lock:
            if robot in self._subs:
                return
            self._subs[robot] = []
        topic = '/%s/%s' % (robot, self.cfg.map_topic)
        updates = '/%s/%s' % (robot, self.cfg.map_updates_topic or self.cfg.map_topic + '_updates')
        subs = [self.create_subscription(OccupancyGrid, topic, lambda m: self._on_map(m, robot), self._map_qos(topic)),
                self.create_subscription(OccupancyGridUpdate, updates, lambda m: self._on_update(m, robot), 10),
                self.create_subscription(PoseWithCovarianceStamped, '/%s/map_merge/prior' % robot,
                                         lambda m: self._on_prior(m, robot), 1),
                self.create_subscription(Empty, '/%s/map_merge/clear_prior' % robot,
                                         lambda m: self._on_clear_prior(robot), 1)]
        with self._lock:
            self._subs[robot] = subs
            self._map_topics[robot] = topic
        self.get_logger().info('robot %s found, subscribed to %s' % (robot, topic))

    def _on_map(self, msg: OccupancyGrid, robot: str) -> None:
        self._input.on_map(robot, lambda: grid_from_msg(msg, self.cfg.max_cells))

    def _on_update(self, msg: OccupancyGridUpdate, robot: str) -> None:
        self._input.on_update(robot, msg.x, msg.y, msg.width, msg.height, msg.data)

    def _on_prior(self, msg: PoseWithCovarianceStamped, robot: str) -> None:
        """A prior in the merged frame (rviz's 2D Pose Estimate with it as the fixed frame). The
        wheels have no tf2_ros: a prior in another frame is refused, saying so."""
        topic = '/%s/map_merge/prior' % robot
        frame = msg.header.frame_id.lstrip('/')
        if frame and frame != self.cfg.merged_map_frame.lstrip('/'):
            self.get_logger().error('ignoring the prior of %s on %s: it is in frame "%s"; give it in the merged '
                                    'frame "%s"' % (robot, topic, frame, self.cfg.merged_map_frame))
            return
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        try:
            events = self.merger.set_prior_in_merged_frame(robot, pose_of(p.x, p.y, q.x, q.y, q.z, q.w))
        except PriorOfReference as e:
            self.get_logger().warning('ignoring the prior of %s on %s: %s' % (robot, topic, e))
            return
        except ValueError as e:   # PriorRefused too
            self.get_logger().error('ignoring the prior of %s on %s: %s' % (robot, topic, e))
            return
        for event in events:
            self.get_logger().warning(event)
        self.get_logger().info('prior of %s from %s: x=%.3f m y=%.3f m in %s' % (robot, topic, p.x, p.y,
                                                                                 self.cfg.merged_map_frame))

    def _on_clear_prior(self, robot: str) -> None:
        if self.merger.clear_prior(robot):
            self.get_logger().info('prior of %s cleared: its pairs are estimated again without it' % robot)
        else:
            self.get_logger().info('/%s/map_merge/clear_prior: %s has no prior' % (robot, robot))

    def _estimation_loop(self) -> None:
        log = self.get_logger()
        while self._running and rclpy.ok():
            period = 1.0 / self.cfg.estimation_rate   # (read every cycle: set at run time)
            t0 = time.monotonic()
            error = None
            try:
                for event in self.merger.estimate():
                    log.info(event)
                self._input.log_reference()
            except Exception as e:   # a bad cycle must not end estimation for good
                log.error('estimation failed: %r' % e)
                error = e
            seconds = time.monotonic() - t0
            self._health.estimated(seconds, error)
            budget = t0 + period - REFRESH_MARGIN - time.monotonic()
            if error is None and budget > 0:
                try:
                    for event in self.merger.refresh(budget):
                        log.info(event)
                except Exception as e:
                    log.error('refreshing links failed: %r' % e)
            if self._state is not None:
                try:
                    self._state.save()
                except OSError as e:
                    log.error('cannot save %s: %s' % (self.cfg.state_file, e), throttle_duration_sec=60.0)
            end = t0 + max(period, seconds)
            while self._running and rclpy.ok() and time.monotonic() < end:
                time.sleep(min(0.1, end - time.monotonic() + 1e-3))

    def _compositing_loop(self) -> None:
        while self._running and rclpy.ok():
            t0 = time.monotonic()
            try:
                grid = self.merger.compose()
                if grid is not None:
                    self._ready = grid
            except Exception as e:
                self.get_logger().error('compositing failed: %r' % e, throttle_duration_sec=10.0)
            time.sleep(max(0.01, 0.5 / self.cfg.merge_rate - (time.monotonic() - t0)))

    # -- outputs
    def _publish_map(self) -> None:
        """The merged map (transient-local) when it changed since the last one sent: cells,
        geometry or a placement (as the ROS 1 node: an unchanged merge sends nothing)."""
        grid = self._ready
        if grid is None:
            return
        sent = self._sent
        if sent is not None and grid is sent[0]:
            return
        placed = {r: pl.T.tobytes() for r, pl in self.merger.placements().items()}
        if sent is not None and placed == sent[1] and same_grid(grid, sent[0]):
            self._sent = (grid, placed)
            return
        stamp = self.get_clock().now().to_msg()
        self._map_pub.publish(grid_to_msg(grid, stamp, self.cfg.merged_map_frame))
        self._meta_pub.publish(metadata(grid, stamp))
        self._sent = (grid, placed)

    def _get_map(self, _req, response):
        """The merged map as published now (gmapping's ``dynamic_map``); an empty map (0 x 0)
        before the reference robot's first map, as ROS 2 services have no error reply."""
        grid = self._ready
        if grid is None:
            self.get_logger().warning('dynamic_map: no merged map yet (no map of the reference robot received)')
            return response
        response.map = grid_to_msg(grid, self.get_clock().now().to_msg(), self.cfg.merged_map_frame)
        return response

    def _reset(self, _req, response):
        self.merger.reset()
        self.get_logger().warning('all transforms forgotten (reset service)')
        response.success, response.message = True, 'all transforms forgotten'
        return response

    def stop(self) -> None:
        """End the estimation and compositing threads (before the node is destroyed)."""
        self._running = False
        for t in self._threads:
            t.join(timeout=5.0)
