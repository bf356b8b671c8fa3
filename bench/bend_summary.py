"""The pure part of bench/bend_sweep.py: a placed robot's error against the truth, its squared
Mahalanobis distance under the placement's covariance, coverage at 95%, the "off" thresholds,
the summary over the cases and the summary line. numpy only (no ROS, no merger): unit-tested
in test/unit/bench/test_bend_summary.py.

Conventions (those of ``placement.Placement``): a pose is (x, y, yaw) of a robot's map frame in
the merged frame (the reference robot's map frame), metres and radians; a covariance is the 3x3
of (x, y, yaw), x, y in metres of the merged frame, yaw in radians. An error vector is
(x - x_true, y - y_true, wrap(yaw - yaw_true)).
"""
from __future__ import annotations

import math
from typing import Any, Dict, Iterable, List, Optional, Sequence

import numpy as np

# chi-square 95% quantiles: 3 dof (x, y, yaw) and 2 dof (position only)
CHI2_3, CHI2_2 = 7.81, 5.99
# a placement is "off" when its position error exceeds OFF[0] metres or its yaw error OFF[1]
# degrees: what the pinning sweep calls placed wrong (bench/tools/pinning_sweep.py RIGHT); OFF_WIDE is
# the coarser count the summary also gives (0.2 m or 2 degrees)
OFF = (0.10, 1.0)
OFF_WIDE = (0.20, 2.0)


def wrap(a: float) -> float:
    """An angle in [-pi, pi)."""
    return float((a + math.pi) % (2.0 * math.pi) - math.pi)


def compose(a: Sequence[float], b: Sequence[float]) -> List[float]:
    """Pose a * b (b expressed in a's frame)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return [a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap(a[2] + b[2])]


def invert(a: Sequence[float]) -> List[float]:
    c, s = math.cos(a[2]), math.sin(a[2])
    return [-(c * a[0] + s * a[1]), s * a[0] - c * a[1], wrap(-a[2])]


def relative(ref: Sequence[float], k: Sequence[float]) -> List[float]:
    """Pose of ``k`` in ``ref``'s frame, both given in a common frame: ref^-1 * k (the truth of a
    placement: robot k's start pose relative to the reference robot's)."""
    return compose(invert(ref), k)


def error_vector(est: Sequence[float], true: Sequence[float]) -> np.ndarray:
    return np.array([est[0] - true[0], est[1] - true[1], wrap(est[2] - true[2])], float)


def mahalanobis2(ev: Sequence[float], cov: Any) -> Optional[float]:
    """Squared Mahalanobis distance ``ev^T cov^-1 ev`` (None when ``cov`` is None, not finite
    or singular). ``ev`` of length 2 uses ``cov``'s x, y block."""
    if cov is None:
        return None
    e = np.asarray(ev, float)
    C = np.asarray(cov, float)[:len(e), :len(e)]
    if not np.all(np.isfinite(C)):
        return None
    C = 0.5 * (C + C.T)
    try:
        return float(e @ np.linalg.solve(C, e))
    except np.linalg.LinAlgError:
        return None


def is_off(err_m: float, err_deg: float, limits: Sequence[float] = OFF) -> bool:
    return err_m > limits[0] or err_deg > limits[1]


def placement_record(robot: str, est: Sequence[float], true: Sequence[float], cov: Any,
                     sigma_pos: Optional[float], weak: bool, via: str = '',
                     fit_true: Optional[Sequence[float]] = None) -> Dict[str, Any]:
    """One placed robot: its error against ``true`` (m, deg), its reported 2-sigma position
    (``sigma_pos``: covariance.position_sigma, 1 sigma, worst direction), the squared
    Mahalanobis distances (3 dof, and 2 dof on position), covered at 95%, off, weak; and, with
    ``fit_true`` (the truth by the maps' best rigid fits), the error against that."""
    ev = error_vector(est, true)
    err_m, err_deg = float(math.hypot(ev[0], ev[1])), float(abs(math.degrees(ev[2])))
    d2 = mahalanobis2(ev, cov)
    d2p = mahalanobis2(ev[:2], cov)
    rec: Dict[str, Any] = {
        'robot': robot, 'via': via, 'est': [float(v) for v in est], 'true': [float(v) for v in true],
        'err': ev.tolist(), 'err_m': err_m, 'err_deg': err_deg,
        'cov': None if cov is None else np.asarray(cov, float).tolist(),
        'sigma2_m': None if sigma_pos is None else 2.0 * float(sigma_pos),
        'd2': d2, 'd2_pos': d2p,
        'in95': None if d2 is None else d2 <= CHI2_3,
        'in95_pos': None if d2p is None else d2p <= CHI2_2,
        'weak': bool(weak), 'off': is_off(err_m, err_deg), 'off_wide': is_off(err_m, err_deg, OFF_WIDE)}
    if fit_true is not None:
        ef = error_vector(est, fit_true)
        rec['fit'] = {'true': [float(v) for v in fit_true], 'err': ef.tolist(),
                      'err_m': float(math.hypot(ef[0], ef[1])), 'err_deg': float(abs(math.degrees(ef[2]))),
                      'd2': mahalanobis2(ef, cov), 'd2_pos': mahalanobis2(ef[:2], cov)}
    return rec


def _share(flags: List[bool]) -> Optional[float]:
    return (sum(1 for f in flags if f) / len(flags)) if flags else None


def summarize(cases: Iterable[Dict[str, Any]]) -> Dict[str, Any]:
    """Over the valid cases (``{'name', 'placements': [record], 'robots': n, ...}``; a case with
    ``invalid`` is counted apart, never in a figure)."""
    cases = list(cases)
    valid = [c for c in cases if not c.get('invalid')]
    recs = [r for c in valid for r in c.get('placements', [])]
    with_cov = [r for r in recs if r.get('d2') is not None]
    off = [r for r in recs if r['off']]
    wide = [r for r in recs if r['off_wide']]
    weak = [r for r in recs if r['weak']]
    worst = max(recs, key=lambda r: r['err_m']) if recs else None
    fits = [r['fit'] for r in recs if r.get('fit') and r['fit'].get('d2') is not None]
    links = [r for c in valid for r in c.get('links', []) if r.get('d2') is not None]
    return {
        'cases': len(valid), 'invalid': [{'name': c['name'], 'invalid': c['invalid']} for c in cases
                                         if c.get('invalid')],
        'robots': sum(int(c.get('robots', 0)) - 1 for c in valid),
        'placements': len(recs), 'with_cov': len(with_cov),
        'in95': _share([r['in95'] for r in with_cov]),
        'in95_pos': _share([r['in95_pos'] for r in with_cov]),
        'off': len(off), 'off_weak': sum(1 for r in off if r['weak']),
        'off_wide': len(wide), 'off_wide_weak': sum(1 for r in wide if r['weak']),
        'weak': len(weak), 'weak_not_off': sum(1 for r in weak if not r['off']),
        'off_in95': sum(1 for r in off if r.get('in95')),
        'worst_m': None if worst is None else worst['err_m'],
        'worst_sigma2_m': None if worst is None else worst['sigma2_m'],
        'worst': None if worst is None else '%s %s' % (worst.get('case', ''), worst['robot']),
        'fit_with_cov': len(fits),
        'fit_in95': _share([f['d2'] <= CHI2_3 for f in fits]),
        'fit_in95_pos': _share([f['d2_pos'] <= CHI2_2 for f in fits]),
        'links': len(links), 'links_in95': _share([r['in95'] for r in links]),
        'links_fit_in95': _share([r['fit']['d2'] <= CHI2_3 for r in links
                                  if r.get('fit') and r['fit'].get('d2') is not None]),
    }


def pct(v: Optional[float]) -> str:
    return '-' if v is None else '%.1f%%' % (100.0 * v)


def metres(v: Optional[float]) -> str:
    return '-' if v is None else '%.3f' % v


def summary_lines(s: Dict[str, Any]) -> List[str]:
    """The summary, the last line being :func:`summary_line`."""
    out = ['placements: %d of %d robots in %d cases (%d not placed); %d with a covariance'
           % (s['placements'], s['robots'], s['cases'], s['robots'] - s['placements'], s['with_cov']),
           'within the 95%% ellipse: %s (x, y, yaw; chi2 3 dof < %.2f), %s (position; 2 dof < %.2f)'
           % (pct(s['in95']), CHI2_3, pct(s['in95_pos']), CHI2_2)]
    if s.get('fit_with_cov'):
        out.append('  against the maps\' best rigid fits instead of the start poses: %s (3 dof), %s (position)'
                   % (pct(s['fit_in95']), pct(s['fit_in95_pos'])))
    out += ['off (> %.2f m or > %.1f deg): %d, flagged weak %d of them, within their 95%% ellipse %d'
            % (OFF[0], OFF[1], s['off'], s['off_weak'], s['off_in95']),
            'off (> %.2f m or > %.1f deg): %d, flagged weak %d of them'
            % (OFF_WIDE[0], OFF_WIDE[1], s['off_wide'], s['off_wide_weak']),
            'flagged weak: %d, of them not off %d' % (s['weak'], s['weak_not_off']),
            'worst: %s m (2-sigma %s m) %s' % (metres(s['worst_m']), metres(s['worst_sigma2_m']), s['worst'] or '')]
    if s.get('links'):
        out.append('links (every kept link, its covariance as placements count it): %d; within the 95%% ellipse '
                   '%s against the starts, %s against the best fits' % (s['links'], pct(s['links_in95']),
                                                                        pct(s['links_fit_in95'])))
    if s['invalid']:
        out.append('INVALID cases: %d (%s)' % (len(s['invalid']), ', '.join(c['name'] for c in s['invalid'])))
    out.append(summary_line(s))
    return out


def summary_line(s: Dict[str, Any]) -> str:
    """``bend sweep: N placements in C cases; within 95% ellipse P%; off K, flagged weak W of
    them; worst E m (2-sigma S m)``: P over the placements with a covariance, 3 dof."""
    p = '-' if s['in95'] is None else '%.1f' % (100.0 * s['in95'])
    return ('bend sweep: %d placements in %d cases; within 95%% ellipse %s%%; off %d, flagged weak %d of them; '
            'worst %s m (2-sigma %s m)' % (s['placements'], s['cases'], p, s['off'], s['off_weak'],
                                           metres(s['worst_m']), metres(s['worst_sigma2_m'])))


# ------------------------------------------------------------------------------ the robots' own maps


def own_maps(cases: Iterable[Dict[str, Any]]) -> Dict[str, Any]:
    """Per log, each robot's final SLAM map against the log's ground truth (a case's ``own_fit``:
    {robot: {'fitness', 'from_start_pose', ...}}) and what its SLAM run cost (the case's
    ``gmapping``: {robot: {'cpu_s', 'processed', 'scans'}}): {'logs': {log: {'maps', 'mean',
    'worst', 'from_start_mean', 'cpu_s_mean', 'cpu_s_max', 'processed', 'scans', 'cases'}},
    'overall': {...the same over every log}, 'unscored': [(case, robot, why)]}. A map that could
    not be scored, or a robot whose SLAM run failed, is named in ``unscored`` and counted in no
    figure (a log with no scored map has None for its figures)."""
    per: Dict[str, Dict[str, Any]] = {}
    unscored: List[List[str]] = []

    def blank() -> Dict[str, Any]:
        return {'fit': [], 'start': [], 'cpu': [], 'processed': 0, 'scans': 0, 'cases': set()}
    allx = blank()
    for c in cases:
        log = str(c.get('log') or c.get('name', '?'))
        x = per.setdefault(log, blank())
        fits = c.get('own_fit') or {}
        for r, g in sorted((c.get('gmapping') or {}).items()):
            f = fits.get(r)
            if g.get('invalid'):
                why = g['invalid']
            elif f is None:
                why = 'not scored'
            else:
                why = f.get('invalid')
            if why or f is None or f.get('fitness') is None:
                unscored.append([str(c.get('name', log)), r, str(why or 'no Fitness')])
                continue
            for y in (x, allx):
                y['fit'].append(float(f['fitness']))
                if f.get('from_start_pose') is not None:
                    y['start'].append(float(f['from_start_pose']))
                if g.get('cpu_s') is not None:
                    y['cpu'].append(float(g['cpu_s']))
                y['processed'] += int(g.get('processed') or 0)
                y['scans'] += int(g.get('scans') or 0)
                y['cases'].add(str(c.get('name', log)))

    def fig(y: Dict[str, Any]) -> Dict[str, Any]:
        def m(v):
            return float(np.mean(v)) if v else None
        return {'maps': len(y['fit']), 'cases': len(y['cases']), 'mean': m(y['fit']),
                'worst': min(y['fit']) if y['fit'] else None, 'from_start_mean': m(y['start']),
                'cpu_s_mean': m(y['cpu']), 'cpu_s_max': max(y['cpu']) if y['cpu'] else None,
                'processed': y['processed'], 'scans': y['scans']}
    return {'logs': {k: fig(v) for k, v in per.items()}, 'overall': fig(allx), 'unscored': unscored}


def own_maps_lines(o: Dict[str, Any], label: str = 'SLAM') -> List[str]:
    """``own_maps`` as a table: per log and over all, the Fitness of the robots' own maps (mean,
    worst), CPU s per robot (mean, largest), scans processed of those in the bags."""
    def f(v, p='%.4f'):
        return '-' if v is None else p % v
    out = ['robots\' own %s maps against the ground truth (Fitness, best of the start pose and 8 headings):'
           % label,
           '  %-14s %5s %5s %8s %8s %12s %14s %9s' % ('log', 'cases', 'maps', 'mean', 'worst', 'from start',
                                                    'CPU s/robot', 'processed')]
    rows = sorted(o['logs'].items()) + [('all', o['overall'])]
    for k, y in rows:
        out.append('  %-14s %5d %5d %8s %8s %12s %14s %9s' % (
            k, y['cases'], y['maps'], f(y['mean']), f(y['worst']), f(y['from_start_mean']),
            '%s (max %s)' % (f(y['cpu_s_mean'], '%.1f'), f(y['cpu_s_max'], '%.1f')),
            '%d/%d' % (y['processed'], y['scans'])))
    if o['unscored']:
        out.append('  not scored: %s' % '; '.join('%s %s: %s' % tuple(u) for u in o['unscored']))
    return out
