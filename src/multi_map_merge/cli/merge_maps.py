"""``merge_maps``: merge saved map_server maps offline with the same core as the node.

    merge_maps A.yaml B.yaml ... -o merged.yaml [--transforms T.yaml] [--reference A]
              [--config map_merge.yaml]

``--transforms`` writes the transforms report: every map frame's pose in the merged frame
(:func:`report.transforms_report`; ``evaluate_map --transforms`` reads it). It is not the
node's state file (``~state_file``, :mod:`state`), which holds the verified links between pairs.

Exit status: 0 merged (even if some maps could not be placed: they are listed with
``merged: false``), 2 bad arguments or a bad input file (the message names it).
"""
from __future__ import annotations

import dataclasses
import math
import os
import sys
from typing import List, Optional

import yaml

from ..core.mapio import MapFileError, load_map, save_map
from ..core.merger import MapMerger
from ..core.report import transforms_report
from ..node_config import NodeConfig
from .args import parser


def main(argv: Optional[List[str]] = None) -> int:
    ap = parser('merge_maps', __doc__)
    ap.add_argument('maps', nargs='+', help='map_server .yaml files, one per robot')
    ap.add_argument('-o', '--output', required=True, help='merged map .yaml to write (+ .pgm)')
    ap.add_argument('--transforms', metavar='T.yaml',
                    help='write the transforms report here: each map frame\'s pose in the merged frame '
                         '(YAML; evaluate_map --transforms reads it)')
    ap.add_argument('--reference', help='file stem of the reference map (default: the first map)')
    ap.add_argument('--config', help='YAML of merger parameters (config/map_merge.yaml keys)')
    a = ap.parse_args(argv)

    cfg_dict = {}
    if a.config:
        try:
            with open(a.config) as f:
                cfg_dict = yaml.safe_load(f) or {}
        except (OSError, yaml.YAMLError) as e:
            print('merge_maps: %s: cannot read config: %s' % (a.config, e), file=sys.stderr)
            return 2
    names: List[str] = []
    grids = []
    for p in a.maps:
        stem = os.path.splitext(os.path.basename(p))[0]
        if stem in names:
            print('merge_maps: %s: two maps named %r (file stems must differ)' % (p, stem), file=sys.stderr)
            return 2
        try:
            grids.append(load_map(p))
        except MapFileError as e:
            print('merge_maps: %s' % e, file=sys.stderr)
            return 2
        names.append(stem)
    reference = a.reference or names[0]
    if reference not in names:
        print('merge_maps: --reference %s is not one of the maps (%s)' % (reference, ', '.join(names)),
              file=sys.stderr)
        return 2
    try:   # the reference is a file stem, not a ROS name: set after the parameters are checked
        # (the node's YAML is read as it is: its node-only parameters are checked, then unused)
        config = NodeConfig.from_dict(cfg_dict, warn=lambda w: print('merge_maps: %s: %s' % (a.config, w),
                                                                     file=sys.stderr))
    except ValueError as e:
        print('merge_maps: %s: %s' % (a.config, str(e).replace('\n', '\n  ')), file=sys.stderr)
        return 2
    merger = MapMerger(dataclasses.replace(config, reference_robot=reference))
    for n, g in zip(names, grids):
        merger.update_map(n, g)
    merger.estimate()
    merged = merger.compose()
    save_map(merged, a.output)
    report = transforms_report(merger, reference, names)
    if a.transforms:
        with open(a.transforms, 'w') as f:
            yaml.safe_dump(report, f, sort_keys=False)
    print('reference: %s' % reference)
    for n, r in report['maps'].items():
        if r['merged']:
            print('  %-30s merged   x=%8.3f m  y=%8.3f m  yaw=%8.2f deg  inlier ratio %.3f  '
                  'inliers %d  agreement %.3f  via %s' % (n, r['x'], r['y'], math.degrees(r['yaw']),
                                                          r['inlier_ratio'], r['inliers'],
                                                          r['agreement'], r['via']))
            if 'sigma_position' in r:
                print('  %-30s          2-sigma position %.3f m%s' % ('', 2 * r['sigma_position'],
                                                                     ' WEAKLY PINNED' if r['weak'] else ''))
        else:
            print('  %-30s NOT merged: %s' % (n, r['reason']))
    for lk in report['links']:
        sigma = 'covariance unknown'
        if 'sigma_position' in lk:
            sigma = '2-sigma position %.3f m' % (2 * lk['sigma_position'])
        print('  link %s -> %s: %s' % (lk['parent'], lk['child'], sigma))
    print('merged map: %s (%dx%d cells, %.3f m)' % (a.output, merged.width, merged.height, merged.resolution))
    return 0
