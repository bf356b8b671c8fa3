"""How ``make accuracy`` scores: a map's best Fitness against the truth (``best_score``), maps
composited at given poses as merge_maps composites (``compose_maps``: the rigid bound, the team at
its true starts, the unbent merge, MRPT's placements), our merge and the peers' (``merge_ours``,
``unbent``, ``merge_peer``: methods of accuracy_condition.Condition), each placement against its
covariance (``placement_checks``)."""
from __future__ import annotations

import math
import os
from typing import Any, Dict, List

import accuracy_common as C
from accuracy_common import MEXPLORE_TOOL, MRPT_TOOL, PY, REPO, TEAM, child_env, run_timed
from accuracy_summary import Invalid


def merge_ours(self, paths, truth, starts):
    from multi_map_merge.core.mapio import load_map
    out = os.path.join(self.run_dir, 'ours')
    os.makedirs(out, exist_ok=True)
    cfg = os.path.join(out, 'config.yaml')
    with open(cfg, 'w') as f:
        f.write('workers: 1   # inline: the benchmark\'s job slots are its CPU budget\n')
        f.write('bend_maps: %s\n' % ('false' if C.ARGS.unbent else 'true'))
    merged, tf = os.path.join(out, 'merged.yaml'), os.path.join(out, 'transforms.yaml')
    for p in (merged, tf):
        if os.path.exists(p):
            os.remove(p)
    cmd = [PY, os.path.join(REPO, 'scripts', 'merge_maps')] + paths + [
        '-o', merged, '--transforms', tf, '--reference', TEAM[0], '--config', cfg]
    r = run_timed(cmd, os.path.join(out, 'merge_maps.log'), child_env(), 1800)
    if r['rc'] != 0 or not os.path.exists(merged) or not os.path.exists(tf):
        return Invalid('merge_maps failed (exit %s, %s)' % (r['rc'], os.path.join(out, 'merge_maps.log'))), None, {}
    import yaml
    with open(tf) as f:
        rep = yaml.safe_load(f)
    n = 1 + sum(1 for v in (rep.get('maps') or {}).values() if v.get('merged'))
    s = best_score(load_map(merged), truth, [starts[rep['reference']]])
    s['transforms'] = rep.get('maps')
    s['wall_s'] = r['wall_s']
    return (s['fitness'] if 'fitness' in s else Invalid(s['invalid'])), '%d/%d' % (n, len(paths)), s

def unbent(self, maps, merged, truth, starts):
    """Our merge's placements (``merged``: merge_ours' details) composited rigidly and
    scored as the merge is."""
    import numpy as np

    from multi_map_merge.core.transforms import se2
    tf = merged.get('transforms') if isinstance(merged, dict) else None
    if tf is None:
        return Invalid('our merge failed'), {}
    ref = TEAM[0]
    poses = {ref: np.eye(3)}
    poses.update({r: se2(v['x'], v['y'], v['yaw']) for r, v in tf.items() if v.get('merged')})
    s = best_score(compose_maps(maps, poses, maps[ref], 'map'), truth, [starts[ref]])
    return (s['fitness'] if 'fitness' in s else Invalid(s['invalid'])), s

def merge_peer(self, peer, paths, maps, truth, starts):
    import numpy as np
    import yaml
    out = os.path.join(self.run_dir, peer)
    os.makedirs(out, exist_ok=True)
    merged, tf = os.path.join(out, 'merged.yaml'), os.path.join(out, 'transforms.yaml')
    for p in (merged, tf):
        if os.path.exists(p):
            os.remove(p)
    tool = MEXPLORE_TOOL if peer == 'mexplore' else MRPT_TOOL
    if peer == 'mexplore':     # its node's own merged /map: no placements to composite
        cmd = [PY, tool] + paths + ['-o', merged, '--settle', '10']
    else:
        cmd = [PY, tool] + paths + ['-o', merged, '--transforms', tf, '--reference', TEAM[0],
                                    '--seed', str(self.seed)]
    log = os.path.join(out, 'merge.log')
    r = run_timed(cmd, log, child_env(), 1800)
    if r['rc'] != 0 or not os.path.exists(merged if peer == 'mexplore' else tf):
        return Invalid('%s failed (exit %s, %s)' % (os.path.basename(tool), r['rc'], log)), None, {}
    if peer == 'mexplore':
        from multi_map_merge.core.mapio import load_map
        s = best_score(load_map(merged), truth, [starts[TEAM[0]]])
        s['wall_s'] = r['wall_s']
        return (s['fitness'] if 'fitness' in s else Invalid(s['invalid'])), 'its merged /map', s
    with open(tf) as f:
        rep = yaml.safe_load(f) or {}
    ref = str(rep.get('reference', TEAM[0]))
    poses = {ref: np.eye(3)}
    for k, v in (rep.get('maps') or {}).items():
        if v.get('merged'):
            c, s_, sc = math.cos(v['yaw']), math.sin(v['yaw']), float(v.get('scale', 1.0))
            poses[str(k)] = np.array([[sc * c, -sc * s_, v['x']], [sc * s_, sc * c, v['y']], [0, 0, 1.0]])
    grid = compose_maps({k: maps[k] for k in poses}, poses, maps[ref], ref + '/map')
    s = best_score(grid, truth, [starts[ref]])
    s['transforms'] = rep.get('maps')
    s['reference'] = ref
    s['wall_s'] = r['wall_s']
    return (s['fitness'] if 'fitness' in s else Invalid(s['invalid'])), '%d/%d' % (len(poses), len(paths)), s



def placement_checks(transforms, own, starts) -> List[Dict[str, Any]]:
    """Per robot our merge placed (``transforms``: merge_maps' ``maps``): its error against
    the truth by the maps' best rigid fits (``own[r]['T']``, relative to the reference's) and
    against the robots' true starts, under its covariance (bend_summary.placement_record)."""
    import numpy as np
    from bend_summary import placement_record

    from multi_map_merge.core.transforms import inverse, xyyaw
    ref = TEAM[0]
    out = []
    for r, v in sorted(transforms.items()):
        if not v.get('merged') or r == ref or 'T' not in own.get(r, {}):
            continue
        fit = xyyaw(inverse(np.array(own[ref]['T'])) @ np.array(own[r]['T']))
        start = xyyaw(inverse(starts[ref]) @ starts[r])
        cov = np.array(v['cov']).reshape(3, 3) if v.get('cov') else None
        rec = placement_record(r, (v['x'], v['y'], v['yaw']), fit, cov, v.get('sigma_position'),
                               bool(v.get('weak')), v.get('via', ''), fit_true=start)
        rec['start'] = rec.pop('fit')     # (placement_record's second truth: here the starts)
        out.append(rec)
    return out


def best_score(grid, truth, inits) -> Dict[str, Any]:
    """The best Fitness of ``grid`` on ``truth`` from each coarse pose of ``inits`` and from
    best_fit_score's eight headings; {'invalid': why} when it cannot be scored."""
    from multi_map_merge.core.grid import GridError
    from multi_map_merge.core.transforms import xyyaw
    from multi_map_merge.lab.evaluate import best_fit_score, score_map
    try:
        cands = [('start pose', score_map(grid, truth, T0)) for T0 in inits]
        cands.append(('best fit', best_fit_score(grid, truth)))
    except GridError as e:
        return {'invalid': 'cannot be scored: %s' % e}
    how, s = max(cands, key=lambda c: c[1].fitness)
    return {'fitness': float(s.fitness), 'inlier_rmse': float(s.inlier_rmse), 'coverage': float(s.coverage),
            'wrong_occupied_m2': float(s.wrong_occupied_m2), 'pose': list(xyyaw(s.T)), 'T': s.T.tolist(),
            'from': how, 'from_start_pose': float(cands[0][1].fitness) if inits else None}


def compose_maps(maps, poses, frame_grid, frame_id):
    """The maps warped by ``poses`` (3x3, map frame -> target frame) and composited as merge_maps
    composites (core/composite: Occupied > Free > Unknown) on ``frame_grid``'s lattice."""
    import numpy as np

    from multi_map_merge.core.composite import composite, lattice_for, warp_patch
    from multi_map_merge.core.config import MergeConfig
    c = MergeConfig()
    lattice = lattice_for(frame_grid)
    patches = []
    for k in sorted(poses):
        g = maps[k]
        kv = g.known_values(c.free_thresh, c.occupied_thresh)
        if kv is not None:
            patches.append(warp_patch(kv[1], kv[0], g.resolution, g.origin, np.asarray(poses[k], float),
                                      lattice, c.max_cells))
    grid = composite(patches, lattice, frame_id, c.max_cells)
    if grid is None:
        raise ValueError('nothing to composite')
    return grid


