"""m-explore's side: ../shared/peers/mexplore/merge_maps_mexplore on the very same map files.

Its tool prints only the median estimation and compositing times of a whole run, so:
  features per map  = estimation of a run on that one map (AKAZE only: with one image there is
                      nothing to match);
  per pair          = estimation of a run on the two maps minus both maps' feature times
                      (matching + bundle adjustment of one pair);
  peak RSS          = ru_maxrss of the mexplore_merge process itself (wait4 on it, through a
                      wrapper placed in a private PEER_WS, so the Python front end is not counted);
  compositing       = its composeGrids(), timed by bench/mexplore_compose.cpp (our driver of its
                      library, built here against the peer's build) in bursts alternated with
                      ours (bench/duel.py): on its own estimate, and on the poses our merger
                      found (the same output: where its own estimate is wrong, its compositing
                      time is that of another output);
  paired estimation = its estimateTransforms(), timed by the same driver, one cycle per burst
                      alternated with one cold cycle of ours (bench/duel.py).
Nothing of m-explore is part of the project; when ../shared is absent every call here says so.
"""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import tempfile
import time

import numpy as np
from inputs import SHARED

PEER = os.path.join(SHARED, 'peers', 'mexplore')
PEER_WS = os.environ.get('PEER_WS', '/tmp/peer_ws')
ENV = dict(os.environ, PATH='/usr/bin:/bin:' + os.environ.get('PATH', ''))

_WRAPPER = r'''#!/usr/bin/python3
import os, subprocess, sys
p = subprocess.Popen([%(real)r] + sys.argv[1:])
_, status, ru = os.wait4(p.pid, 0)
with open(%(rss)r, 'a') as f:
    f.write('%%d\n' %% ru.ru_maxrss)
sys.exit(os.waitstatus_to_exitcode(status))
'''


def available():
    """(True, '') or (False, why): builds the peer with its build.sh when ../shared is here
    but PEER_WS is not built yet."""
    if not os.path.isdir(PEER):
        return False, '../shared/peers/mexplore is absent: m-explore columns NOT measured'
    if not os.path.exists(os.path.join(PEER_WS, 'mexplore_merge')):
        print('building m-explore into %s (../shared/peers/mexplore/build.sh) ...' % PEER_WS, flush=True)
        r = subprocess.run([os.path.join(PEER, 'build.sh')], capture_output=True, text=True, env=ENV)
        if r.returncode != 0 or not os.path.exists(os.path.join(PEER_WS, 'mexplore_merge')):
            return False, 'm-explore did not build: %s' % (r.stdout + r.stderr)[-500:]
    return True, ''


def _build_driver(exe):
    """Compile bench/mexplore_compose.cpp against the peer's built library, as the peer's
    build.sh compiles its own driver."""
    ws = PEER_WS
    src = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'mexplore_compose.cpp')
    libs = subprocess.run(['pkg-config', '--libs', 'opencv4'], capture_output=True, text=True,
                          env=ENV).stdout.split()
    cmd = (['g++', '-O2', '-std=c++14', '-o', exe, src, '-I', os.path.join(ws, 'src', 'map_merge', 'include'),
            '-I', '/usr/include/opencv4', os.path.join(ws, 'devel', 'lib', 'libcombine_grids.a')] + libs +
           ['-lroscpp', '-lrosconsole', '-lroscpp_serialization', '-lrostime', '-lcpp_common', '-lboost_system'])
    r = subprocess.run(cmd, capture_output=True, text=True, env=ENV)
    if r.returncode != 0:
        raise RuntimeError('cannot build %s: %s' % (exe, r.stderr[-500:]))


def live_node():
    p = os.path.join(PEER_WS, 'devel', 'lib', 'multirobot_map_merge', 'map_merge')
    return p if os.path.exists(p) else None


class TimedOut(RuntimeError):
    """A :meth:`Peer.run` stopped at its time-out."""


class Peer:
    def __init__(self, root):
        self.root = tempfile.mkdtemp(prefix='peer_', dir=root)
        self.ws = os.path.join(self.root, 'ws')
        os.makedirs(self.ws)
        self.rss_file = os.path.join(self.root, 'rss.txt')
        w = os.path.join(self.ws, 'mexplore_merge')
        with open(w, 'w') as f:
            f.write(_WRAPPER % {'real': os.path.join(PEER_WS, 'mexplore_merge'), 'rss': self.rss_file})
        os.chmod(w, 0o755)
        self.n = 0

    def run(self, paths, reps, timeout=None):
        """One merge_maps_mexplore run: (timing JSON, T.yaml report, peak RSS MB, wall s).
        ``timeout`` (seconds, None: none): past it the run's whole process tree is stopped and
        :class:`TimedOut` raised."""
        import yaml
        self.n += 1
        out = os.path.join(self.root, 'run%03d' % self.n)
        os.makedirs(out)
        if os.path.exists(self.rss_file):
            os.remove(self.rss_file)
        cmd = [os.path.join(PEER, 'merge_maps_mexplore')] + list(paths) + [
            '-o', os.path.join(out, 'm.yaml'), '--transforms', os.path.join(out, 'T.yaml'), '--reps', str(reps)]
        t = time.time()
        # a session of its own: on time-out its whole tree (the front end and mexplore_merge) is stopped
        p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env=dict(ENV, PEER_WS=self.ws), start_new_session=True)
        try:
            stdout, stderr = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.communicate()
            why = 'its cycle on the %d maps did not end within %.0f s: stopped' % (len(paths), timeout)
            raise TimedOut(why) from None
        wall = time.time() - t
        if p.returncode != 0:
            raise RuntimeError('m-explore failed: %s' % stderr[-300:])
        timing = json.loads(stdout.strip().splitlines()[-1])
        rep = yaml.safe_load(open(os.path.join(out, 'T.yaml')))
        rss = max(int(x) for x in open(self.rss_file).read().split()) / 1024.0
        return timing, rep, rss, wall

    def compose_cmd(self, paths, reps, poses=None, own_confidence=1.0):
        """Command line of bench/mexplore_compose.cpp serving compositing bursts (bench/duel.py)
        of ``reps`` composeGrids() each: of the maps placed at ``poses`` ({index: [x, y, yaw]},
        pose of map k's frame in map 0's frame, metres and radians; map 0 is the reference), or,
        without poses, of m-explore's own estimate (estimateTransforms once, ``own_confidence``
        as merge_maps_mexplore's default)."""
        return self._driver_cmd((['--own', repr(own_confidence)] if poses is None else []), paths, reps, poses)

    def estimate_cmd(self, paths, reps, confidence=1.0):
        """Command line of bench/mexplore_compose.cpp serving estimation bursts (bench/duel.py)
        of ``reps`` estimateTransforms() each, as merge_maps_mexplore times them."""
        return self._driver_cmd(['--estimate', repr(confidence)], paths, reps, None)

    def _driver_cmd(self, flags, paths, reps, poses):
        import yaml
        exe = os.path.join(self.root, 'mexplore_compose')
        if not os.path.exists(exe):
            _build_driver(exe)
        args = [exe] + list(flags) + ['--serve', str(reps)]
        for k, path in enumerate(paths):
            pose = [0.0, 0.0, 0.0] if poses is None else poses.get(str(k), poses.get(k))
            if pose is None:
                continue
            m = yaml.safe_load(open(path))
            img = m['image'] if os.path.isabs(m['image']) else os.path.join(os.path.dirname(path), m['image'])
            args += [img, repr(float(m['resolution'])), repr(float(m['origin'][0])),
                     repr(float(m['origin'][1]))] + [repr(float(v)) for v in pose]
        return args

    def measure(self, paths, truth, reps, pairs, full=True):
        """m-explore's figures for one configuration (see module docstring)."""
        from multi_map_merge.core.transforms import pose_distance, se2
        res = {}
        feat = {}
        for k in sorted({k for ab in pairs for k in ab}):
            timing, _, _, _ = self.run([paths[k]], reps)
            feat[k] = timing['estimate_ms']
        res['features_ms'] = float(np.median(list(feat.values())))
        pair = []
        for a, b in pairs:
            timing, _, _, _ = self.run([paths[a], paths[b]], reps)
            pair.append(timing['estimate_ms'] - feat[a] - feat[b])
        # Matching a pair small enough costs less than the noise of three runs' timings: the
        # difference can come out <= 0, which is no figure (None; the raw differences are kept).
        res['pair_raw_ms'] = pair
        res['pair_ms'] = float(np.median(pair)) if np.median(pair) > 0 else None
        if not full:
            return res
        timing, rep, rss, wall = self.run(paths, reps)
        stems = [os.path.splitext(os.path.basename(p))[0] for p in paths]
        placed = sum(1 for v in rep['maps'].values() if v.get('merged'))
        errs = {}
        if truth is not None and rep['reference'] in stems:
            j = stems.index(rep['reference'])
            for k, s in enumerate(stems):
                v = rep['maps'].get(s)
                if v and v.get('merged'):
                    T_true = np.linalg.inv(np.array(truth[j])) @ np.array(truth[k])
                    d, ang = pose_distance(se2(v['x'], v['y'], v['yaw']), T_true)
                    errs[s] = (float(d), math.degrees(float(ang)))
        res.update({'estimate_ms': timing['estimate_ms'], 'compose_ms': timing['compose_ms'],
                    'rss_mb': rss, 'placed': placed, 'reference': rep['reference'], 'errors': errs,
                    'scales': [round(v['scale'], 4) for v in rep['maps'].values() if v.get('merged')],
                    'max_err_m': max([e[0] for e in errs.values()]) if errs else None,
                    'max_err_deg': max([e[1] for e in errs.values()]) if errs else None,
                    'wall_s': wall})
        return res
