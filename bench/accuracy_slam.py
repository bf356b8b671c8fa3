"""One SLAM run of ``make accuracy`` (rbpf_slam_replay, or gmapping's replayer where ROS has it)
in a roscore of its own, and the peers that can run here."""
from __future__ import annotations

import os
import re
import shlex
import shutil
from typing import Any, Dict, Optional

import accuracy_common as C
from accuracy_cache import write_json
from accuracy_common import DEFAULT_SLAM, PY, REPO, SLAM_MEMORY_GB, SLAMS, Roscore, run_timed, say, stamp


def replay_binary(slam: str = DEFAULT_SLAM) -> Optional[str]:
    """The replayer of ``slam`` (SLAMS) that ROS finds: rbpf_slam_replay of our workspace
    (``make build``), or slam_gmapping_replay of a gmapping ROS has (an overlay or the system's);
    None when there is none."""
    s = SLAMS[slam]
    for p in os.environ.get('CMAKE_PREFIX_PATH', '').split(':') + ['/opt/ros/noetic']:
        exe = os.path.join(p, 'lib', s['package'], s['replay'])
        if p and os.access(exe, os.X_OK):
            return exe
    return None


def slam_missing(slam: str) -> str:
    """Why ``slam`` cannot run here (its replayer was not found): one line for an INVALID row."""
    if slam == 'gmapping':
        return ('gmapping missing: ROS here has no gmapping (no lib/gmapping/slam_gmapping_replay under '
                'CMAKE_PREFIX_PATH or /opt/ros/noetic; its source is gone and Debian has no package, '
                'issue 47): use --slam rbpf')
    return ('rbpf_slam missing: no lib/multi_map_merge/rbpf_slam_replay under CMAKE_PREFIX_PATH '
            '(make build builds it; source the workspace)')


def bag_scans(bag: str, topic: str) -> int:
    import rosbag
    with rosbag.Bag(bag) as b:
        info = b.get_type_and_topic_info().topics.get(topic)
    return int(info.message_count) if info is not None else 0



def run_gmapping(exe: str, bag: str, topic: str, name: str, seed: int, config: str, prefix: str,
                 head: Dict[str, Any], timeout: float, port: int, ros_home: str,
                 extra_params: Optional[Dict[str, Any]] = None, slam: str = 'gmapping',
                 snapshot_every: Optional[float] = None) -> Dict[str, Any]:
    """One real SLAM run: ``exe`` (``slam``'s replayer, SLAMS: rbpf_slam_replay or
    slam_gmapping_replay, the same flags) on ``topic`` of ``bag`` with the settings of ``config``
    (gmapping's parameter names; ``extra_params`` over it) under the node's name and ``name``'s
    frames, in a roscore of its own (a free port from ``port``), saving its last map to
    ``prefix``.yaml (``scripts/save_map``). Returns ``head`` + what it did (scans in the bag,
    processed, for rbpf_slam those without TF, exit code, times, map), with ``invalid`` naming why
    when it made no usable map; written to ``prefix``.json last (its presence means the run is
    complete)."""
    label, node = SLAMS[slam]['label'], SLAMS[slam]['node']
    for ext in ('.yaml', '.pgm', '.log', '.json', '.core.log'):
        if os.path.exists(prefix + ext):
            os.remove(prefix + ext)
    meta_path = prefix + '.json'
    scans = bag_scans(bag, topic)
    import yaml
    with open(config) as f:
        settings = dict(yaml.safe_load(f) or {})
    settings.update(extra_params or {})
    params = {'/%s/%s' % (node, k): v for k, v in settings.items()}
    params.update({'/%s/base_frame' % node: '%s/base_footprint' % name,
                   '/%s/odom_frame' % node: '%s/odom' % name,
                   '/%s/map_frame' % node: '%s/map' % name})
    on_done = ' '.join(shlex.quote(x) for x in [PY, os.path.join(REPO, 'scripts', 'save_map'),
                                                '-f', prefix, '--topic', '/map', '--timeout', '60'])
    cmd = [exe, '--bag_filename', bag, '--scan_topic', topic, '--seed', str(seed), '--on_done', on_done]
    snap_dir = prefix + '.snap'
    if os.path.isdir(snap_dir):
        shutil.rmtree(snap_dir)
    if snapshot_every:       # rbpf_slam_replay: the map every S s of bag time, into PREFIX.snap/
        os.makedirs(snap_dir)
        cmd += ['--snapshot_every', '%g' % snapshot_every,
                '--snapshot_prefix', os.path.join(snap_dir, os.path.basename(prefix))]
    prlimit = shutil.which('prlimit')
    if SLAM_MEMORY_GB > 0 and prlimit:
        cmd = [prlimit, '--as=%d' % int(SLAM_MEMORY_GB * (1 << 30)), '--'] + cmd
    with Roscore(port, prefix + '.core.log', ros_home) as core:
        core.set_params(params)
        r = run_timed(cmd, prefix + '.log', core.env, timeout)
    with open(prefix + '.log', errors='replace') as f:
        log = f.read()
    processed = len(re.findall(r'^update frame \d+', log, re.M))
    dropped = log.count('Dropping old scan')
    # rbpf_slam_replay's last line: R scans received, P processed, K without TF
    last = re.findall(r'^rbpf_slam_replay: (\d+) scans received, (\d+) processed, (\d+) without TF', log, re.M)
    # and, with gyro_scale_learning: gyro scale K applied, estimate E, from N steps
    scale = re.findall(r'^rbpf_slam_replay: gyro scale ([\d.]+) applied, estimate ([\d.]+), from (\d+) steps',
                       log, re.M)
    meta = dict(head)
    if last:
        meta.update(received=int(last[-1][0]), without_tf=int(last[-1][2]))
    if scale:
        meta['gyro_scale'] = {'applied': scale[-1][0], 'estimate': scale[-1][1], 'steps': int(scale[-1][2])}
    meta.update({'slam': slam, 'name': name, 'bag': bag, 'topic': topic,
                 'scans': scans, 'processed': processed, 'dropped': dropped, 'rc': r['rc'],
                 'wall_s': r['wall_s'], 'cpu_s': r['cpu_s'], 'map': prefix + '.yaml', 'log': prefix + '.log'})
    why = None
    # (MRPT's serialising of a particle's map fails an assertion when its buffer cannot grow)
    oom_sign = next((m for m in ('std::bad_alloc', 'CMemoryStream::resize') if m in log), None)
    out_of_memory = oom_sign is not None or r['rc'] == -9
    if out_of_memory:
        why = ('%s ran out of memory (exit %s: %s; its limit %s GiB, SLAM_MEMORY_GB) after %d of %d scans (%s)'
               % (label, r['rc'], oom_sign or 'killed', SLAM_MEMORY_GB, processed, scans, prefix + '.log'))
    elif r['timed_out']:
        why = '%s did not finish within %.0f s' % (label, timeout)
    elif processed == 0:
        why = '%s processed no scan of %d (%s)' % (label, scans, prefix + '.log')
    elif r['rc'] != 0:
        why = '%s exited %s (%s)' % (os.path.basename(exe), r['rc'], prefix + '.log')
    elif not os.path.exists(prefix + '.yaml'):
        why = 'no map saved (%s)' % (prefix + '.log')
    if why:
        meta['invalid'] = why
    if not C.PROCS.stopping.is_set() and not out_of_memory:   # (out of memory: tried again next time)
        write_json(meta_path, meta)           # last, at once: its presence means the run is complete
    meta['cached'] = False
    return meta


# ------------------------------------------------------------------------------ peers

def peers_available(build: bool) -> Dict[str, Optional[str]]:
    """peer -> None (usable) or why not. MRPT's driver is built here (``build``), not inside a
    timed merge; m-explore is used only where its node is installed."""
    import mrpt_merge
    import peer
    out: Dict[str, Optional[str]] = {}
    ok, why = peer.available()
    out['mexplore'] = None if ok else why
    ok, why = mrpt_merge.available()
    if ok and build:
        try:
            say('%s accuracy: MRPT driver: %s' % (stamp(), mrpt_merge.binary()))
        except RuntimeError as e:
            ok, why = False, 'MRPT\'s driver did not build: %s' % e
    out['mrpt'] = None if ok else why
    return out


