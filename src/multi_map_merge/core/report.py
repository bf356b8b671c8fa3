"""The transforms report, what ``merge_maps --transforms`` writes: every map frame's placement in
the merged frame, or why it is not merged, and every verified link with how well the grids pin
it. For people and scripts (``evaluate_map --transforms`` reads it); the merger never reads it
back. Not the node's state file (:mod:`state`), which holds the verified links to restore."""
from __future__ import annotations

from typing import Dict, List

from .merger import MapMerger
from .state import placement_dict

# digits a placement's numbers are written with in the transforms report
DIGITS = {'x': 6, 'y': 6, 'yaw': 6, 'inlier_ratio': 4, 'agreement': 4}


def transforms_report(merger: MapMerger, reference: str, names: List[str]) -> Dict:
    """The transforms report (``merge_maps --transforms``): every map frame's placement in the
    merged (reference) frame (:func:`state.placement_dict`, rounded), or why it is not merged;
    and every verified link between two maps with how well the grids pin it (``sigma_position``,
    ``cov``)."""
    placements = merger.placements()
    status = merger.status()
    maps: Dict[str, Dict] = {}
    for n in names:
        if n == reference:
            continue
        pl = placements.get(n)
        if pl is None:
            st = status.get(n)
            why = st.last_attempt.reason if st and st.last_attempt else 'no estimate'
            maps[n] = {'merged': False, 'reason': why}
            continue
        d = placement_dict(pl)
        maps[n] = dict(merged=True, **{k: _rounded(k, v) for k, v in d.items()})
    links = []
    for e in sorted(merger.export_state()['edges'], key=lambda e: (e['parent'], e['child'])):
        links.append({k: _rounded(k, e[k]) for k in ('parent', 'child', 'x', 'y', 'yaw', 'sigma_position', 'cov')
                      if k in e})
    return {'reference': reference, 'maps': maps, 'links': links}


def _rounded(key: str, v):
    """A number of the transforms report as written: DIGITS decimals, a covariance to 6
    significant digits."""
    if key in DIGITS:
        return round(v, DIGITS[key])
    if key == 'cov':
        return [float('%.6g' % x) for x in v]
    return v
