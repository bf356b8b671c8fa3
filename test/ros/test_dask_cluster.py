#!/usr/bin/env python3
"""rostest: the live merger node aligning its pairs on a real Dask cluster (``~dask_scheduler``).

The test starts a real ``dask-scheduler`` and two ``dask-worker`` processes on 127.0.0.1 (the
scheduler on a free port; the workers import this package through the sourced workspace's
PYTHONPATH), then the merger through ``launch/map_merge.launch`` with a config naming that
scheduler. It plays four robots whose maps are pieces of the Intel map moved by known poses (as
test_merge_node.py), so every merged ``/map`` is compared cell by cell with the truth and every
TF ``map -> tb3_N/map`` with the true pose:

1. small first maps of three robots: merged right, the work done by the cluster (the scheduler's
   task stream: the node's tasks, at least one per map's features plus one per link), no
   fallback line;
2. the three maps grow and the fourth robot's first map comes; the first worker to start one of
   that cycle's tasks is killed (SIGKILL) right then (a worker plugin armed by the test: the
   cycle's tasks may take only milliseconds): the other worker does that task again and finishes
   the cycle (the scheduler reschedules), every map merged right, still no fallback line;
3. the scheduler killed (SIGKILL), the fourth map grows: the node falls back to its local pool
   with exactly one log line on /rosout, and merges the new map version right.

Skips (with the reason) when ``distributed`` (python3-distributed) cannot be imported."""
import os
import shutil
import signal
import subprocess
import tempfile
import time
import unittest

import rospkg
import rostest
import yaml
from rosgraph_msgs.msg import Log
from rostest_helpers import (
    FOUR_POSES,
    FOUR_ROBOTS,
    START_RADIUS,
    Collector,
    PiecesTest,
    known_cells,
    stop_launch,
    union_known_of,
    wait_until,
)

from multi_map_merge.lab.loopback_cluster import LoopbackCluster
from multi_map_merge.ros.tools import revealed

try:
    import distributed
    NO_DISTRIBUTED = None
except ImportError as e:   # optional: only ~dask_scheduler needs it
    distributed = None
    NO_DISTRIBUTED = ('python3-distributed is not installed (import distributed: %s): it is optional, only '
                      '~dask_scheduler needs it; install it (Debian/Ubuntu python3-distributed) to run this test' % e)

PKG = 'multi_map_merge'
ROBOTS = FOUR_ROBOTS     # on test_merge_node.py's pieces of the Intel map
TASK = 'run_on_worker'  # the key prefix of the node's tasks (runtime/cluster.py submits run_on_worker)
FALLBACK = 'Dask cluster'   # in the node's one line when the cluster fails (runtime/cluster.py's lost)
# the merger's rates in this test (config/map_merge.yaml's, faster), as merge_node.test's
NODE_PARAMS = dict(estimation_rate=2.0, merge_rate=4.0, discovery_rate=2.0, map_drift=0.0, map_drift_yaw=0.0,
                   reference_robot='tb3_0')


class KillOnTask:
    """A worker plugin (``distributed``'s WorkerPlugin interface) armed on every worker: the first
    worker to start one of the node's tasks kills itself with SIGKILL right then, its task begun
    and not done: a worker lost mid-cycle, mid-task, whatever the tasks' lengths. It first writes
    ``marker`` (created exclusively: one worker only) with its address, process id and the task's
    key."""

    name = 'mmm-kill-on-task'

    def __init__(self, marker):
        self.marker = marker
        self.address = None

    def setup(self, worker):
        self.address = worker.address

    def transition(self, key, start, finish, **kwargs):
        if finish != 'executing' or not str(key).startswith(TASK):
            return
        try:
            fd = os.open(self.marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:    # the other worker was first
            return
        os.write(fd, yaml.safe_dump(dict(address=self.address, pid=os.getpid(), key=str(key))).encode())
        os.fsync(fd)
        os.close(fd)
        os.kill(os.getpid(), signal.SIGKILL)

    @staticmethod
    def read(marker):
        """What the killed worker wrote in ``marker`` (a dict), None until it is there whole."""
        try:
            with open(marker) as f:
                d = yaml.safe_load(f)
        except (OSError, yaml.YAMLError):
            return None
        return d if isinstance(d, dict) and {'address', 'pid', 'key'} <= set(d) else None


class DaskCluster(LoopbackCluster):
    """The loopback cluster (:class:`LoopbackCluster`), read for the node's tasks."""

    def pids(self):
        """Worker address -> its process id."""
        return self.client.run(os.getpid)

    def compute_ms(self):
        """The node's finished task -> milliseconds it computed (its task stream's 'compute' span;
        a dict in newer ``distributed``, a tuple (action, start, stop) in 2.x)."""
        out = {}
        for t in self.client.get_task_stream():
            for ss in t.get('startstops', ()):
                action, start, stop = (ss['action'], ss['start'], ss['stop']) if isinstance(ss, dict) else ss[:3]
                if action == 'compute' and str(t['key']).startswith(TASK):
                    out[str(t['key'])] = 1e3 * (stop - start)
        return out

    def worker_of(self):
        """The node's finished task -> the worker address that finished it."""
        return dict(self.tasks(TASK))

    def per_worker(self):
        """Worker address -> how many of the node's tasks it finished."""
        out = {}
        for _, w in self.tasks(TASK):
            out[w] = out.get(w, 0) + 1
        return out

    def arm(self, plugin):
        """Register a worker plugin on every worker."""
        self.client.register_worker_plugin(plugin, name=plugin.name)


class TestDaskCluster(PiecesTest):

    NODE = 'test_dask_cluster'
    ROBOTS = ROBOTS
    POSES = FOUR_POSES
    LATE = ('tb3_3',)   # no map topic until its first map (step 2)
    cluster = None
    launch = None
    tmp = None
    steps = set()   # the steps passed (each test needs the one before; all three: the logs removed)

    @classmethod
    def setUpClass(cls):
        if NO_DISTRIBUTED:
            raise unittest.SkipTest(NO_DISTRIBUTED)
        cls.tmp = tempfile.mkdtemp(prefix='mmm_dask_cluster_')
        try:
            super().setUpClass()
            cls.logs = Collector('/rosout', Log, keep=lambda m: m.name == '/map_merge', queue_size=500)
            cls.cluster = DaskCluster(cls.tmp)
            address = cls.cluster.start()
            config = os.path.join(cls.tmp, 'map_merge.yaml')
            pkg = rospkg.RosPack().get_path(PKG)
            with open(os.path.join(pkg, 'config', 'map_merge.yaml')) as f:
                params = yaml.safe_load(f)
            params.update(NODE_PARAMS, dask_scheduler=address)
            with open(config, 'w') as f:
                yaml.safe_dump(params, f)
            with open(os.path.join(cls.tmp, 'launch.log'), 'w') as out:
                cls.launch = subprocess.Popen(['roslaunch', PKG, 'map_merge.launch', 'config:=' + config,
                                               'output:=log'], stdout=out, stderr=subprocess.STDOUT,
                                              start_new_session=True)
            print('cluster at %s (logs in %s), merger launched' % (address, cls.tmp))
        except BaseException:
            cls.tearDownClass()
            raise

    @classmethod
    def tearDownClass(cls):
        if cls.launch is not None:
            stop_launch(cls.launch)
            cls.launch = None
        if cls.cluster is not None:
            cls.cluster.stop()
            cls.cluster = None
        if getattr(cls, 'player', None) is not None:
            super().tearDownClass()
        if cls.tmp and len(cls.steps) == 3:
            shutil.rmtree(cls.tmp, ignore_errors=True)
        elif cls.tmp:
            print('a step did not pass: the cluster\'s and the launch\'s logs are kept in %s' % cls.tmp)

    # -- what the test reads
    def fallback_lines(self):
        return [m.msg for m in self.logs.messages() if FALLBACK in m.msg]

    def merge_of(self, grids, after, timeout, what):
        """Wait for the robots of ``grids`` (robot k's map, the first len(grids) robots) all
        merged (reported after ``after``) and a /map knowing as many cells as their maps at their
        true poses (within 5%); assert that /map against the truth and each robot's TF."""
        robots = ROBOTS[:len(grids)]
        pieces = [(g, T) for g, (_, T) in zip(grids, self.pieces)]
        target = union_known_of(self.world, pieces)
        t0 = time.time()
        merged = wait_until(lambda: self.listen.all_merged(robots, after), timeout)
        self.assertTrue(merged, '%s: not every robot merged within %.0f s: %s' % (
            what, timeout, {r: (s[0].message if s else None) for r, s in
                            ((r, self.listen.status(r)) for r in robots)}))
        msg = wait_until(lambda: self.listen.map_where(lambda m: abs(known_cells(m) - target) < 0.05 * target),
                         max(10.0, timeout - (time.time() - t0)))
        last = self.listen.latest_map()
        self.assertIsNotNone(msg, '%s: no /map of these maps: the latest knows %s cells, the maps %d' % (
            what, known_cells(last) if last is not None else None, target))
        print('%s: merged %.1f s after, /map knows %d cells (the maps %d)' % (
            what, time.time() - after, known_cells(msg), target))
        self.assert_matches_truth(msg, what, pieces)
        for k in range(len(robots)):
            self.assert_tf(k, what)
        return msg

    def need(self, step):
        if step not in self.steps:
            self.skipTest('needs step %s, which did not pass' % step)

    # -- the steps
    def test_1_the_cluster_merges(self):
        """Small first maps of three robots: merged right, the work done by the cluster, no
        fallback line."""
        type(self).small = {r: revealed(g, START_RADIUS) for r, (g, _) in zip(ROBOTS, self.pieces)}
        first = ROBOTS[:-1]
        t0 = time.time()
        for r in first:
            self.player.publish(r, self.small[r])
        self.merge_of([self.small[r] for r in first], t0, 90.0, 'small maps')
        done = self.cluster.per_worker()
        print('tasks done by the cluster: %s' % done)
        # at least the features of each map and one pair per link placing the two other robots
        self.assertGreaterEqual(sum(done.values()), len(first) + len(first) - 1,
                                'the cluster did not do the pair work: %s tasks' % done)
        self.assertEqual(self.fallback_lines(), [])
        self.steps.add(1)

    def test_2_a_worker_killed_mid_cycle(self):
        """The three maps grow and the last robot's first map comes: the first worker to start
        one of that cycle's tasks killed then; the other does that task again and finishes the
        cycle, every map merged right, no fallback line."""
        self.need(1)
        c = self.cluster
        pids = c.pids()
        self.assertEqual(len(pids), 2, pids)
        before = c.per_worker()
        done_before = set(c.worker_of())
        grids = [g for g, _ in self.pieces[:-1]] + [self.small[ROBOTS[-1]]]
        # that cycle: the first worker to start one of its tasks is killed right then (SIGKILL; the
        # grown maps are tracked from their kept links, tasks of a few ms: gone before a kill from
        # here would land)
        marker = os.path.join(self.tmp, 'killed.yaml')
        c.arm(KillOnTask(marker))
        t0 = time.time()
        for r, g in zip(ROBOTS, grids):
            self.player.publish(r, g)
        killed = wait_until(lambda: KillOnTask.read(marker), 30.0)
        self.assertTrue(killed, 'no worker started a task of the node within 30 s of the new maps')
        victim, task = killed['address'], killed['key']
        proc = next(p for p in c.workers if p.pid == pids[victim])
        self.assertEqual(killed['pid'], proc.pid)
        proc.wait(timeout=30)
        self.assertEqual(proc.returncode, -signal.SIGKILL)
        t_kill = time.time()
        print('%.2f s after the new maps, the worker %s (pid %d) killed (SIGKILL) starting %s'
              % (t_kill - t0, victim, proc.pid, task))
        survivor = next(w for w in pids if w != victim)
        self.merge_of(grids, t_kill, 90.0, 'new maps, a worker killed')
        after = c.per_worker()
        new = {k: ms for k, ms in c.compute_ms().items() if k not in done_before}
        print('tasks done by the cluster: before %s, after %s; this cycle\'s took %s ms' % (
            before, after, ', '.join('%.0f' % ms for ms in new.values())))
        self.assertGreater(after.get(survivor, 0), before.get(survivor, 0),
                           'the remaining worker did none of the cycle\'s tasks')
        # the task the killed worker had begun was done again by the other one
        self.assertEqual(c.worker_of().get(task), survivor, 'the killed worker\'s task %s' % task)
        self.assertEqual(list(c.client.scheduler_info()['workers']), [survivor])
        self.assertEqual(self.fallback_lines(), [], 'a worker lost is no cluster lost')
        self.steps.add(2)

    def test_3_the_scheduler_killed(self):
        """The scheduler killed, the last map grows: the local pool merges it, one log line."""
        self.need(2)
        c = self.cluster
        c.close_client()
        DaskCluster.kill(c.scheduler)
        t0 = time.time()
        grids = [g for g, _ in self.pieces]
        self.player.publish(ROBOTS[-1], grids[-1])
        line = wait_until(self.fallback_lines, 60.0)
        self.assertTrue(line, 'no log line of the lost cluster on /rosout within 60 s')
        print('%.1f s after the scheduler was killed: %s' % (time.time() - t0, line))
        self.merge_of(grids, time.time(), 90.0, 'the last map grown, the scheduler killed')
        # a few more estimation cycles (2 Hz) later, every robot still merged: still the one line
        t1 = time.time()
        self.assertTrue(wait_until(lambda: self.listen.all_merged(ROBOTS, t1 + 2.0), 20.0),
                        'not every robot merged 2 s later')
        lines = self.fallback_lines()
        self.assertEqual(len(lines), 1, lines)
        self.assertIn(c.address, lines[0])
        self.assertIn('local workers', lines[0])
        self.steps.add(3)

if __name__ == '__main__':
    rostest.rosrun(PKG, 'dask_cluster', TestDaskCluster)
