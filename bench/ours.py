#!/usr/bin/env python3
"""Our side of one benchmark configuration, run in a fresh process (so its peak RSS is its own).

    python3 bench/ours.py SPEC.json          -> one JSON line on stdout
    python3 bench/ours.py --serve SPEC.json  -> compositing bursts on demand (see serve())
    python3 bench/ours.py --serve-estimate SPEC.json  -> cold estimation cycles on demand
    python3 bench/ours.py --memory SPEC.json -> the node's memory on these maps (see memory())

SPEC: {"paths": [map yaml...], "truth": [3x3 pose of map k in map 0's frame] or null,
"reps": R, "pairs": [[a, b], ...]}. Measures, with the project's defaults (MergeConfig()):
  features_ms   FeatureExtractor on one map's levels (median over the maps of the pairs, R reps)
  pair_ms       MapMerger.align_robots(a, b): matching + RANSAC + verification + ICP, in this
                process (median over the pairs, R reps)
  pool_start_ms starting the merger's worker pool (once per node; not part of cold_ms)
  cold_ms       estimate() of a new MapMerger holding every map as the node runs it (features +
                every pair + placement, in the merger's worker processes where its maps call for
                them, with ``defer_refinement``: a new link's covariance search and the joint
                refinement of a first placement left for the spare time); median of R such cycles,
                each of a new merger (cold_first_ms: the process's first). This is what the first
                TF waits for.
  refine_ms     refresh() right after it: the work left for the spare time (the placements are
                then those of a cycle without ``defer_refinement``)
  warm_ms       estimate() again with unchanged maps
  ingest_ms     a map's classification as it arrives (update_map: levels, known box and the
                values compositing warps), per map; not part of compose_ms
  compose_first_ms  compose() of that merger for the first time (every map warped), right
                after its estimation, whose work ran in the worker processes while this one
                waited: its caches and OpenCV's threads have gone cold (median of R)
  compose_ms    compose() with every map warped again, COMPOSE_REPS times back to back, median
  live_ms       compose() + publishing with one robot's map changed, the others' warps kept
                (round robin over the robots but the reference), COMPOSE_REPS times, median
  publish_ms    ros.convert.grid_to_msg (numpy_msg OccupancyGrid) + msg.serialize(BytesIO) of
                the merged grid, COMPOSE_REPS times back to back, median (publish_first_ms: once
                per cycle, after the first compose)
  rss_sum_mb    this process's ru_maxrss plus each worker process's VmHWM (shared pages counted
                once per process: an upper bound, and not the node's imports: see --memory)
and the placements (``poses``: x, y, yaw of each placed map's frame in map 0's frame, metres and
radians), scored against ``truth`` when given.
"""
import io
import json
import math
import resource
import sys
import time

import numpy as np

COMPOSE_REPS = 9   # back-to-back compositing runs per burst, both sides (bench/duel.py)


def publish(grid):
    """(seconds, bytes) of what the node does to publish a merged grid: a numpy_msg
    OccupancyGrid, serialised."""
    import rospy

    from multi_map_merge.ros.convert import grid_to_msg
    t = time.perf_counter()
    msg = grid_to_msg(grid, rospy.Time(0), 'map')
    buf = io.BytesIO()
    msg.serialize(buf)
    return time.perf_counter() - t, buf.tell()


def worker_peaks_mb():
    """VmHWM of the merger's estimation workers (forkserver children, not ours: read /proc)."""
    import multi_map_merge.runtime.pool as mm
    total = 0.0
    if mm._POOL is not None:
        for pid in list(mm._POOL._processes):
            try:
                with open('/proc/%d/status' % pid) as f:
                    total += [int(line.split()[1]) for line in f if line.startswith('VmHWM')][0] / 1024.0
            except (OSError, IndexError):
                pass
    return total


def _hold(fn, *args):
    """fn(*args), then hold the worker a moment so that every worker of the pool gets a task."""
    fn(*args)
    time.sleep(0.2)


def start_pool(cfg):
    """Start the merger's worker pool (and import the package in every worker), as the node
    does once at its first cycle; returns the ms it took."""
    import multi_map_merge.runtime.pool as mm
    from multi_map_merge.core.workers import PRELOAD
    t = time.perf_counter()
    pool = mm.shared(cfg.workers, PRELOAD)
    if pool is not None:
        from multi_map_merge.core.pair import compute_features
        tiny = np.zeros((8, 8), np.uint8)
        n = mm._POOL_SIZE
        list(pool.map(_hold, [compute_features] * n, [cfg] * n, [tiny] * n))
    return (time.perf_counter() - t) * 1000.0


def score(placements, truth, n):
    """Per placed robot (reference excluded): (translation error m, rotation error deg)."""
    from multi_map_merge.core.transforms import pose_distance
    errs = {}
    if truth is None:
        return errs
    for k in range(1, n):
        name = 'r%02d' % k
        if name in placements:
            d, a = pose_distance(placements[name].T, np.array(truth[k]))
            errs[name] = (float(d), math.degrees(float(a)))
    return errs


def compose_burst(m):
    """COMPOSE_REPS back-to-back compose() + publishing of ``m``'s merged map, every map warped
    again each time (as m-explore's composeGrids() warps them): medians in ms. Then as many
    with one robot's map changed (round robin over the robots but the reference, its patch
    dropped as a new map of it drops it), every other patch kept: a live cycle's compositing
    when one robot's gmapping map arrived ('live_ms', compose + publish)."""
    comp, pub = [], []
    for _ in range(COMPOSE_REPS):
        m._compositor.reset()
        t = time.perf_counter()
        merged = m.compose()
        comp.append(time.perf_counter() - t)
        pub.append(publish(merged)[0])
    others = sorted(n for n in m.placements() if n != m.reference)
    live = []
    for k in range(COMPOSE_REPS if others else 0):
        m._compositor.forget(others[k % len(others)])
        t = time.perf_counter()
        merged = m.compose()
        dt = time.perf_counter() - t
        live.append(dt + publish(merged)[0])
    return {'compose_ms': float(np.median(comp)) * 1000.0, 'publish_ms': float(np.median(pub)) * 1000.0,
            'ms': float(np.median(np.add(comp, pub))) * 1000.0,
            'live_ms': float(np.median(live)) * 1000.0 if live else None}


def serve(spec):
    """Estimate once, print {"ready": true, "poses": ...}, then one compose_burst() JSON line per
    line read on stdin, until EOF (bench/duel.py)."""
    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.core.mapio import load_map
    from multi_map_merge.core.merger import MapMerger
    from multi_map_merge.core.transforms import xyyaw
    m = MapMerger(MergeConfig())
    for k, p in enumerate(spec['paths']):
        m.update_map('r%02d' % k, load_map(p))
    m.estimate()
    P = m.placements()
    poses = {k: list(xyyaw(P['r%02d' % k].T)) for k in range(len(spec['paths'])) if 'r%02d' % k in P}
    print(json.dumps({'ready': True, 'poses': poses}), flush=True)
    for _ in sys.stdin:
        print(json.dumps(compose_burst(m)), flush=True)


def serve_estimate(spec):
    """Start the worker pool, print {"ready": true}, then for every line read on stdin one cold
    estimation cycle (a new MapMerger holding every map, as in main(): the node's, with
    ``defer_refinement``), printed as {"ms": ...,
    "placed": ...}: bench/tools/versus.py alternates these cycles with another commit's (bench/duel.py),
    run_bench.py with m-explore's."""
    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.core.mapio import load_map
    from multi_map_merge.core.merger import MapMerger
    cfg = MergeConfig()
    grids = [load_map(p) for p in spec['paths']]
    start_pool(cfg)
    print(json.dumps({'ready': True}), flush=True)
    for _ in sys.stdin:
        m = MapMerger(cfg)
        for k, g in enumerate(grids):
            m.update_map('r%02d' % k, g)
        t = time.perf_counter()
        m.estimate(defer_refinement=True)
        ms = (time.perf_counter() - t) * 1000.0
        print(json.dumps({'ms': ms, 'placed': len(m.placements()) - 1}), flush=True)


def _read_pgm(path, flags=None):
    """An 8-bit binary PGM (what map_saver and save_map write) as cv2.imread(path, GRAYSCALE)
    returns it; anything else through cv2.imread."""
    import cv2
    with open(path, 'rb') as f:
        raw = f.read()
    fields, pos = [], 0
    while len(fields) < 4 and raw[:2] == b'P5':
        while raw[pos:pos + 1].isspace():
            pos += 1
        if raw[pos:pos + 1] == b'#':
            pos = raw.index(b'\n', pos)
            continue
        end = pos
        while not raw[end:end + 1].isspace():
            end += 1
        fields.append(raw[pos:end])
        pos = end
    if len(fields) == 4 and int(fields[3]) == 255:
        w, h = int(fields[1]), int(fields[2])
        return np.frombuffer(raw, np.uint8, w * h, pos + 1).reshape(h, w).copy()
    return cv2.imread(path, cv2.IMREAD_GRAYSCALE if flags is None else flags)


def maps_as_the_node_reads_them(paths):
    """The map files ``paths`` as Grids, read without cv2.imread (see :func:`memory`)."""
    from multi_map_merge.core import mapio
    mapio.cv2 = type('cv2_without_imread', (), {'imread': staticmethod(_read_pgm), 'IMREAD_GRAYSCALE': 0})
    return [mapio.load_map(p) for p in paths]


def node_cycle(cfg, grids):
    """What the node does with the maps in one cold cycle: a new merger holding every map,
    estimate() (with ``defer_refinement``), compose(), the merged grid as a message, serialised;
    then the spare time's refresh(), compose() and message again. Returns the merger."""
    from multi_map_merge.core.merger import MapMerger
    m = MapMerger(cfg)
    for k, g in enumerate(grids):
        m.update_map('r%02d' % k, g)
    m.estimate(defer_refinement=True)
    publish(m.compose())
    m.refresh(math.inf)          # the spare time before the next cycle
    publish(m.compose())
    return m


def memory(spec):
    """The node's memory on these maps, as bench/memtree.py's watch() measures it from outside:
    the node's imports (multi_map_merge.ros.node), its worker pool started as the node starts it
    (before any thread), then cycles of what the node does with the maps: a merger holding every
    map (new each cycle: cold), estimate(), compose(), the merged grid as a message, serialised;
    ``reps`` cycles, and more until ``min_seconds`` have passed: the tree is sampled (a sample
    takes tens of ms, a house's cycle 60), and a sampled peak approaches the real one only over
    many cycles. Prints {"placed": ..., "cycles": ...} when done, then waits for stdin to close.

    The maps are read without cv2.imread: the node gets them as messages, and imread's probing of
    its decoders maps about 10 MB of GDAL's library that the node never touches."""
    import multi_map_merge.ros.node  # noqa: F401  (the node's imports, first, as in the node)
    from multi_map_merge.core import workers
    from multi_map_merge.core.config import MergeConfig
    workers.start_pool(0)
    cfg = MergeConfig()
    grids = maps_as_the_node_reads_them(spec['paths'])
    t0, cycles = time.monotonic(), 0
    while cycles < int(spec.get('reps', 3)) or time.monotonic() - t0 < float(spec.get('min_seconds', 0)):
        m = node_cycle(cfg, grids)
        cycles += 1
    time.sleep(0.1)
    print(json.dumps({'placed': len(m.placements()) - 1, 'cycles': cycles}), flush=True)
    sys.stdin.read()


def main():
    if sys.argv[1] == '--memory':
        return memory(json.load(open(sys.argv[2])))
    if sys.argv[1] == '--serve':
        return serve(json.load(open(sys.argv[2])))
    if sys.argv[1] == '--serve-estimate':
        return serve_estimate(json.load(open(sys.argv[2])))
    spec = json.load(open(sys.argv[1]))
    import multi_map_merge.runtime.pool as mm
    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.core.features import FeatureExtractor
    from multi_map_merge.core.mapio import load_map
    from multi_map_merge.core.merger import MapMerger
    from multi_map_merge.core.robot_map import RobotMap

    paths, truth, reps = spec['paths'], spec.get('truth'), int(spec['reps'])
    pairs = [tuple(p) for p in spec['pairs']]
    grids = [load_map(p) for p in paths]
    cfg = MergeConfig()
    med = lambda v: float(np.median(v)) * 1000.0  # noqa: E731

    # (1) features of one map, as the merger computes them
    fe = FeatureExtractor(cfg.akaze_threshold, cfg.max_features, cfg.feature_cells)
    feat = []
    for k in sorted({k for ab in pairs for k in ab}):
        lv = grids[k].levels(cfg.free_thresh, cfg.occupied_thresh)
        for _ in range(reps):
            t = time.perf_counter()
            fe(lv)
            feat.append(time.perf_counter() - t)

    # (1b) ingestion: what update_map does with a map as it arrives, on a fresh copy each time
    from multi_map_merge.core.grid import Grid
    ingest = []
    for g in grids:
        for _ in range(reps):
            data = g.data.copy()
            t = time.perf_counter()
            Grid(data, g.resolution, g.origin).known_values()
            ingest.append(time.perf_counter() - t)

    # (2)-(4) one pair in this process: features cached first, so only the pair is timed
    m0 = MapMerger(cfg)
    rms = [RobotMap('r%02d' % k, g, k + 1, 0.0).set_working_resolution(g.resolution) for k, g in enumerate(grids)]
    pair = []
    for a, b in pairs:
        m0._workers.features_of(rms[a])
        m0._workers.features_of(rms[b])
        for _ in range(reps):
            t = time.perf_counter()
            m0.align_robots(rms[a], rms[b])
            pair.append(time.perf_counter() - t)

    # The node starts its worker pool once, at its first cycle: start it (and import the
    # package in every worker) outside the timed cold cycle, and report that cost apart.
    pool_start = start_pool(cfg)

    # full cycle: cold (new merger: no feature, pair or wall cache of its own), warm (unchanged
    # maps), compositing, publishing
    cold, refine, warm, comp, comp_again, pub = [], [], [], [], [], []
    for _ in range(reps):
        m = MapMerger(cfg)
        for k, g in enumerate(grids):
            m.update_map('r%02d' % k, g)
        t = time.perf_counter()
        m.estimate(defer_refinement=True)
        cold.append(time.perf_counter() - t)
        t = time.perf_counter()
        m.refresh(math.inf)
        refine.append(time.perf_counter() - t)
        t = time.perf_counter()
        m.estimate(defer_refinement=True)
        warm.append(time.perf_counter() - t)
        t = time.perf_counter()
        merged = m.compose()
        comp.append(time.perf_counter() - t)
        t = time.perf_counter()
        m.compose()
        comp_again.append(time.perf_counter() - t)
        pub.append(publish(merged)[0])

    b2b = compose_burst(m)
    published_bytes = publish(merged)[1]

    P = m.placements()
    errs = score(P, truth, len(grids))
    from multi_map_merge.core.transforms import xyyaw
    poses = {k: list(xyyaw(P['r%02d' % k].T)) for k in range(len(grids)) if 'r%02d' % k in P}
    print(json.dumps({
        'features_ms': med(feat), 'pair_ms': med(pair), 'cold_ms': med(cold), 'warm_ms': med(warm),
        'cold_first_ms': cold[0] * 1000.0, 'pool_start_ms': pool_start, 'refine_ms': med(refine),
        'ingest_ms': med(ingest), 'compose_first_ms': med(comp), 'compose_ms': b2b['compose_ms'],
        'compose_again_ms': med(comp_again),
        'publish_first_ms': med(pub), 'publish_ms': b2b['publish_ms'], 'live_ms': b2b['live_ms'],
        'published_bytes': published_bytes,
        'rss_sum_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0 + worker_peaks_mb(),
        'workers': len(mm._POOL._processes) if mm._POOL is not None else 1,
        'robots': len(grids), 'placed': len(P) - 1,
        'errors': errs, 'poses': poses, 'compose_reps': COMPOSE_REPS,
        'max_err_m': max([e[0] for e in errs.values()]) if errs else None,
        'max_err_deg': max([e[1] for e in errs.values()]) if errs else None,
        'merged_cells': int(merged.width * merged.height),
        'map_cells': int(np.median([g.width * g.height for g in grids])),
    }))


if __name__ == '__main__':
    main()
