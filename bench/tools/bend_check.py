"""What bending the maps (core/deform.py, ~bend_maps) can and does gain, on one team's maps.

    bench/bench.py bend-check DIR TRUTH_FILE [--world WORLD.yaml] [--spacing 2.5]   (default world: TRUTH_FILE's)

DIR holds the team's final gmapping maps ``tb3_0..3.yaml`` (e.g. a ``make accuracy`` cache
folder ``/tmp/mmm_accuracy/gmapping/house-s2-...``); TRUTH_FILE is the bag generator's truth file
(each robot's start in the world). Prints the merged Fitness (lab/evaluate, as make accuracy
scores it) of:

- **rigid**: our placements composited rigidly (``bend_maps`` false);
- **bent**: the same placements with every map bent onto the others (``bend_maps`` true);
- **bent onto the world**: the same field pulled by the world itself (the ground truth as one
  more map, held fixed) instead of by the other maps: how far the field can bend when the
  evidence is perfect;
- per robot, its walls that miss the world (further than 0.10 m) in the rigid merge, and the
  share of those that no other robot's map knows (outside every other map's known cells):
  what no merger can learn from the other maps.
"""
from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np
import yaml
from accuracy_scoring import best_score, compose_maps  # noqa: E402

from multi_map_merge.core import deform  # noqa: E402
from multi_map_merge.core.composite import composite, lattice_for, warp_patch  # noqa: E402
from multi_map_merge.core.config import MergeConfig  # noqa: E402
from multi_map_merge.core.mapio import load_map  # noqa: E402
from multi_map_merge.core.merger import MapMerger  # noqa: E402
from multi_map_merge.core.transforms import apply, cell_to_metric, inverse, se2  # noqa: E402

TEAM = ['tb3_0', 'tb3_1', 'tb3_2', 'tb3_3']


def bent_grid(maps, poses, fields, cfg):
    lat = lattice_for(maps[TEAM[0]])
    patches = []
    for n in sorted(poses):
        g = maps[n]
        box, values = g.known_values(cfg.free_thresh, cfg.occupied_thresh)
        if n in fields:
            patches.append(deform.warp_field_patch(values, box, g.resolution, g.origin, fields[n], lat, cfg.max_cells))
        else:
            patches.append(warp_patch(values, box, g.resolution, g.origin, poses[n], lat, cfg.max_cells))
    return composite(patches, lat, 'map', cfg.max_cells)


def unseen_share(maps, poses, T_world, world_walls, cfg):
    """Per robot: (walls missing the world in the rigid merge, the share of those outside every
    other map's known cells)."""
    from scipy.spatial import cKDTree
    tree = cKDTree(world_walls)
    out = {}
    for n in poses:
        g = maps[n]
        w = apply(poses[n], deform.wall_points(g.levels(cfg.free_thresh, cfg.occupied_thresh), g.resolution, g.origin))
        d, _ = tree.query(apply(T_world, w))
        miss = w[d > 0.10]
        seen = np.zeros(len(miss), bool)
        for o in poses:
            if o == n:
                continue
            go = maps[o]
            to_cells = inverse(cell_to_metric(go.resolution, go.origin)) @ inverse(poses[o])
            cells = np.round(apply(to_cells, miss)).astype(int)
            inside = (cells[:, 0] >= 0) & (cells[:, 0] < go.width) & (cells[:, 1] >= 0) & (cells[:, 1] < go.height)
            lv = go.levels(cfg.free_thresh, cfg.occupied_thresh)
            known = np.zeros(len(miss), bool)
            known[inside] = lv[cells[inside, 1], cells[inside, 0]] > 0
            seen |= known
        out[n] = (len(miss), float((~seen).mean()) if len(miss) else 0.0)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bend_check.py', description=__doc__.split('\n\n')[0])
    ap.add_argument('dir', help='folder with tb3_0..3.yaml')
    ap.add_argument('truth_file', help="the bag generator's truth file (robots' starts)")
    ap.add_argument('--world', help="the ground-truth map (default: the truth file's world, as make_robot_bags "
                                    "wrote it: the home or the AWS house of ../shared/data)")
    ap.add_argument('--spacing', type=float, default=MergeConfig().bend_node_spacing, help='metres between nodes')
    a = ap.parse_args(argv)
    with open(a.truth_file) as f:
        truth = yaml.safe_load(f)
    starts = {n: se2(*r['start']) for n, r in truth['robots'].items()}
    # the truth file names its world relative to itself
    world = load_map(a.world or os.path.join(os.path.dirname(os.path.abspath(a.truth_file)), truth['world']))
    maps = {n: load_map(os.path.join(a.dir, n + '.yaml')) for n in TEAM}
    cfg = MergeConfig(reference_robot=TEAM[0], workers=1)
    m = MapMerger(cfg)
    for n in TEAM:
        m.update_map(n, maps[n])
    m.estimate()
    poses = {n: p.T for n, p in m.placements().items()}
    rigid = best_score(compose_maps(maps, poses, maps[TEAM[0]], 'map'), world, [starts[TEAM[0]]])
    walls = {n: deform.wall_points(maps[n].levels(cfg.free_thresh, cfg.occupied_thresh), maps[n].resolution,
                                   maps[n].origin) for n in poses}
    drift, drift_yaw = cfg.map_drift, math.radians(cfg.map_drift_yaw)
    fields = deform.fit_fields(walls, poses, TEAM[0], a.spacing, drift, drift_yaw)
    bent = best_score(bent_grid(maps, poses, fields, cfg), world, [starts[TEAM[0]]])
    # the world as one more map, held where the rigid merge's score put it
    T_world = np.array(rigid['T'])
    world_walls = deform.wall_points(world.levels(cfg.free_thresh, cfg.occupied_thresh), world.resolution, world.origin)
    oracle_poses = dict(poses, world=inverse(T_world))
    oracle = deform.fit_fields(dict(walls, world=world_walls), oracle_poses, TEAM[0], a.spacing, drift, drift_yaw,
                               fixed=['world'])
    onto_world = best_score(bent_grid(maps, poses, oracle, cfg), world, [starts[TEAM[0]]])
    print('%s: %d of 4 placed' % (a.dir, len(poses)))
    print('  rigid                 %.4f' % rigid['fitness'])
    print('  bent                  %.4f  (largest node move %s)' % (bent['fitness'], ', '.join(
        '%s %.2f m' % (n, f.largest()) for n, f in sorted(fields.items()))))
    print('  bent onto the world   %.4f' % onto_world['fitness'])
    for n, (k, share) in sorted(unseen_share(maps, poses, T_world, world_walls, cfg).items()):
        print('  %s: %4d walls miss the world (rigid); %.0f%% of them where no other map knows the cells'
              % (n, k, 100 * share))
    return 0


if __name__ == '__main__':
    sys.exit(main())
