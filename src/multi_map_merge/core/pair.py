"""Steps (2)-(4) (docs/design.md) for one pair of maps, as plain functions of plain data, so that they can run in
worker processes (see :mod:`merger`): match, RANSAC, verify on the grids, refine.

Worker processes keep the estimation's Python work off the node's interpreter: threads would
share its GIL with the timers that publish /map and TF. What a process derives from a map
for the next pair is kept in :mod:`cache`.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Optional, Tuple

import numpy as np

from . import bend, cache, covariance, drift, matching, verify
from .config import MergeConfig
from .pair_data import (  # noqa: F401  (PairInput, PairResult, crop_known, compute_features: this module's API too)
    CROP_MARGIN,
    PairInput,
    PairResult,
    at_one_scale,
    compute_features,
    crop_cells,
    crop_known,
    describe_version,
    grid_cells,
    known_of,
    wall_field_of,
    wall_points_of,
    walls_of,
)
from .refine import refine
from .transforms import (
    apply,
    cell_to_metric,
    image_to_pose,
    inverse,
    pose_distance,
    pose_to_image,
    se2,
    turn_between,
    within,
    within_tolerance,
)


def prior_link(config: MergeConfig, pa: PairInput, ch: PairInput) -> Optional[np.ndarray]:
    """The pose of ``ch``'s map frame in ``pa``'s that the configured initial poses give (3x3),
    None when either robot has none."""
    priors = config.initial_poses
    if pa.name not in priors or ch.name not in priors:
        return None
    return inverse(se2(*priors[pa.name])) @ se2(*priors[ch.name])


def contradicts_prior(config: MergeConfig, pa: PairInput, ch: PairInput, A: np.ndarray) -> str:
    """Why the link contradicts the configured initial poses ('' when it does not, or when
    either robot has none). With priors, of two look-alike placements (a building of
    identical halves) only the one near where the robots started can be accepted."""
    P = prior_link(config, pa, ch)
    if P is None:
        return ''
    T = image_to_pose(grid_cells(A, pa, ch), pa.resolution, pa.origin, ch.resolution, ch.origin)
    if not within(T, P, config.initial_pose_tolerance):
        d, a = pose_distance(T, P)
        tol_d, tol_a = config.initial_pose_tolerance
        return ('contradicts initial poses: %.2f m, %.1f deg from them (tolerance %.2f m, %.1f deg)'
                % (d, math.degrees(a), tol_d, math.degrees(tol_a)))
    return ''


def refined(config: MergeConfig, pa: PairInput, ch: PairInput, A: np.ndarray,
            max_distance: Optional[float] = None) -> np.ndarray:
    """ICP polish of ``A`` on the walls; it may only polish, never move the estimate away.
    ``max_distance``: ICP's first pairing distance (cells), when less than RANSAC's threshold
    will do (a pose known to within a cell)."""
    field_a = wall_field_of(pa)
    pts_b = wall_points_of(ch)
    gate = config.ransac_threshold if max_distance is None else min(max_distance, config.ransac_threshold)
    A2 = refine(field_a, pts_b, A, max_distance=gate)
    if A2 is None:
        return A
    # how far the walls moved (at their centre: the grid's corner can be metres away, where a
    # small turn looks like a big shift)
    centre = np.append(pts_b.mean(axis=0), 1.0) if len(pts_b) else np.array([0.0, 0.0, 1.0])
    d = np.hypot(*((A2 - A) @ centre)[:2])
    return A2 if d <= 3 * config.ransac_threshold and turn_between(A2, A) <= math.radians(5) else A


# two placements of a child closer than this (metres, radians; the child's centre, its turn)
# are one placement found twice, not an ambiguity
AMBIGUITY_APART = (0.5, math.radians(5.0))


def align_pair(config: MergeConfig, pa: PairInput, ch: PairInput, seed: int = 0,
               pin: bool = True) -> PairResult:
    """Cells of ``ch``'s grid -> cells of ``pa``'s grid: (2) match, (3) rigid RANSAC + inlier
    ratio, (4) verification on the grids and ICP refinement. The best-agreeing accepted
    hypothesis is returned, or the best rejected one with its reason (also when a clearly
    different hypothesis verifies nearly as well: ambiguous, see :func:`_check_ambiguity`).
    ``pin`` False: an accepted result's covariance search is left for :func:`pin_later`
    (``pin_deferred``); a result refused for too little evidence is searched now all the same
    (its corroboration needs the covariance)."""
    r = _align_crops(config, pa, ch, seed)
    if r.few_evidence or (r.accepted and pin):
        _pin(config, pa, ch, r)
    elif r.accepted:
        r.pin_deferred = True
    if r.A is not None:
        r.A = grid_cells(r.A, pa, ch)
    return r


def pin_later(config: MergeConfig, pa: PairInput, ch: PairInput, r: PairResult) -> PairResult:
    """The covariance search :func:`align_pair` left for later (``r.pin_deferred``), on the
    same maps: ``r`` as :func:`align_pair` with ``pin`` would have returned it (its pose
    possibly corrected, its covariance, bend, centre and turns)."""
    r = dataclasses.replace(r, A=crop_cells(r.A, pa, ch), pin_deferred=False)
    _pin(config, pa, ch, r)
    r.A = grid_cells(r.A, pa, ch)
    return r


def track_pair(config: MergeConfig, pa: PairInput, ch: PairInput, A: np.ndarray, pin: bool = False) -> PairResult:
    """A kept link followed onto new versions of its maps, as a scan matcher tracks: ``A`` (cells
    of ``ch``'s grid -> cells of ``pa``'s grid: the kept link on the current grids) polished by
    ICP on the walls (:func:`refined`), then verified on the grids and gated as a feature
    hypothesis is, bar the features' gates (no features are matched: ``pa.features`` and
    ``ch.features`` may be None). Milliseconds where :func:`align_pair` takes a tenth of a
    second or more. The result's ``tracked`` is True; its inlier fields are zero (the merger keeps
    the link's own). ``pin``: an accepted result's covariance computed too (:func:`_pin`, a few
    milliseconds more; for a kept link that has none: its walls said too little when aligned)."""
    A0 = crop_cells(A, pa, ch)
    h = PairResult(refined(config, pa, ch, A0) if config.refine else A0, tracked=True)
    tol = config.agreement_tolerance
    h.agreement, h.overlap = verify.agreement(pa.levels, ch.levels, h.A, tol, (known_of(pa)[0], known_of(ch)[0]),
                                              walls_of(pa, tol))
    _judge(config, pa, ch, h, features=False)
    if h.accepted and pin:
        _pin(config, pa, ch, h)
    h.A = grid_cells(h.A, pa, ch)
    return h


def _cost_field(p: PairInput) -> covariance.CostField:
    """The wall cost of a parent for :func:`covariance.pinning`, from the distances ICP uses."""
    f = wall_field_of(p)
    if not f.ok:
        return covariance.CostField(p.levels)
    return covariance.CostField(p.levels, f.dist_flat[:-1].reshape(f.shape), (int(f.offset[0]), int(f.offset[1])))


def _offset_outer(A2: np.ndarray, A: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """outer(d, d) of the perturbation d (dx, dy cells, dyaw about ``centre``) from ``A`` to ``A2``."""
    D = A2 @ inverse(A)
    d = np.array([*(apply(D, centre[None, :])[0] - centre), math.atan2(D[1, 0], D[0, 0])])
    return np.outer(d, d)


def _pin(config: MergeConfig, pa: PairInput, ch: PairInput, r: PairResult) -> None:
    """An accepted estimate's covariance (``r.cov``, in the parent's metric frame; None when
    its walls say too little), from :func:`covariance.pinning` around ``r.A`` (between the
    crops' cells). Where the search finds a pose whose walls meet clearly better than ICP's
    (ICP stopped in a local minimum: along a corridor, a wall's end a few cells off), that
    pose, polished by ICP, replaces ``r.A`` if it also verifies at least as well."""
    field = cache.derived('costfield', pa, _cost_field)
    pts = wall_points_of(ch)
    p = covariance.pinning(pa.levels, ch.levels, r.A, field, pts)
    if p is None:
        return
    cov = p.cov
    if p.cost_best < p.cost - covariance.BETTER_COST:
        A2 = refined(config, pa, ch, p.A, 1.5) if config.refine else p.A
        cost2 = covariance.mean_cost(field, pts, A2)
        if cost2 is not None and cost2 < p.cost - covariance.BETTER_COST:
            tol = config.agreement_tolerance
            ag, ov = verify.agreement(pa.levels, ch.levels, A2, tol, (known_of(pa)[0], known_of(ch)[0]),
                                      walls_of(pa, tol))
            if ag >= r.agreement and ov >= config.min_overlap_cells:
                # the search's moments about its best pose, plus how far ICP moved it (no search
                # again: ICP polished the pose within the search's window)
                r.A, r.agreement, r.overlap, cov = A2, ag, ov, p.cov_best + _offset_outer(A2, p.A, p.centre)
    # a map that bends: the halves of the overlap want poses apart, which the walls' likelihood
    # about one pose does not see
    spread = 0.5 * (bend.rms_spread(wall_points_of(pa)) + bend.rms_spread(wall_points_of(ch)))
    b = bend.across_halves(wall_field_of(pa), p.points, r.A, pa.resolution, p.centre, spread)
    if b is not None:
        cov = cov + b.cov_cells()
        r.bend = b.metres
    T = image_to_pose(grid_cells(r.A, pa, ch), pa.resolution, pa.origin, ch.resolution, ch.origin)
    centre = p.centre + np.array(pa.offset, np.float64)
    r.cov = covariance.metric_covariance(cov, centre, T, pa.resolution, pa.origin)
    W = cell_to_metric(pa.resolution, pa.origin)
    r.centre = tuple(float(v) for v in W[:2, :2] @ centre + W[:2, 2])
    # how far each map turned on the way from its origin to the overlap, where its walls tell:
    # the drift's model error measured rather than assumed (drift.py)
    r.parent_turn = drift.turn(pa.levels, pa.resolution, _origin_cell(pa), p.centre)
    r.child_turn = drift.turn(ch.levels, ch.resolution, _origin_cell(ch), apply(inverse(r.A), p.centre[None, :])[0])


def _origin_cell(p: PairInput) -> np.ndarray:
    """(col, row) of the crop's cells where its map frame's origin lies."""
    return apply(inverse(cell_to_metric(p.resolution, p.origin)), np.zeros((1, 2)))[0] - np.array(p.offset, np.float64)


def _judge(c: MergeConfig, pa: PairInput, ch: PairInput, h: PairResult, features: bool = True) -> None:
    """Pass ``h`` (its inliers, inlier ratio, agreement and overlap set) through every gate:
    ``h.accepted``, or ``h.reason`` for the first gate it fails. ``features`` False: a tracked
    link (:func:`track_pair`), which matched no features, passes the grids' gates only."""
    contradiction = contradicts_prior(c, pa, ch, h.A)
    if contradiction:
        h.reason = contradiction
    elif h.overlap < c.min_overlap_cells:
        h.reason = 'overlap %d cells < %d' % (h.overlap, c.min_overlap_cells)
    elif h.agreement < c.min_agreement:
        h.reason = 'grids disagree: agreement %.2f < %.2f' % (h.agreement, c.min_agreement)
    elif not features:
        h.accepted = True
    elif h.inlier_ratio < c.min_inlier_ratio:
        h.reason = 'inlier ratio %.3f < %.3f' % (h.inlier_ratio, c.min_inlier_ratio)
    elif h.inliers < c.few_inliers and h.agreement < c.few_inliers_min_agreement:
        # A look-alike place yields few agreeing matches and walls that agree only in the
        # main; right links of few inliers agree almost perfectly (docs/measurements.md)
        h.reason = ('too little evidence: %d inliers and agreement %.3f (under %d inliers a link needs %.2f)'
                    % (h.inliers, h.agreement, c.few_inliers, c.few_inliers_min_agreement))
        h.few_evidence = True
    else:
        h.accepted = True


def prior_guess(config: MergeConfig, pa: PairInput, ch: PairInput) -> Optional[np.ndarray]:
    """The link the priors give (cells of ``ch``'s crop -> cells of ``pa``'s crop), None when
    either robot has none."""
    P = prior_link(config, pa, ch)
    if P is None:
        return None
    return crop_cells(pose_to_image(P, pa.resolution, pa.origin, ch.resolution, ch.origin), pa, ch)


# the widest window searched around a prior (metres, degrees): a prior given by a click in rviz
# is rough, the tolerance may be wide, and the search's cost grows with the window
PRIOR_SEARCH_AT_MOST = (1.5, 30.0)


def _near_prior(config: MergeConfig, pa: PairInput, ch: PairInput, src: np.ndarray, dst: np.ndarray,
                matches: int) -> Optional[PairResult]:
    """The link searched on the walls near the one the priors give, when both robots have
    one: a correlative search of the child's walls over the priors' tolerance around it
    (:func:`covariance.search`), polished by ICP, then every gate of a feature hypothesis
    (:func:`_judge`). RANSAC proposes only placements the features support, and where two
    maps overlap by a strip (a building's halves, each mapped by one robot) the features there
    are too few for the right one to be among them, while a look-alike elsewhere has many:
    the priors say where to look instead. Few feature matches agree with such a link, so it
    must verify as well as any link of few inliers (``few_inliers_min_agreement``). None when
    there is no prior, or nothing to search."""
    A0 = prior_guess(config, pa, ch)
    if A0 is None:
        return None
    tol_d, tol_a = config.initial_pose_tolerance
    half = int(math.ceil(min(tol_d, PRIOR_SEARCH_AT_MOST[0]) / pa.resolution))
    # turns about the child's map frame origin (its start pose), as the tolerance is measured:
    # the window is then the tolerance's, wherever the walls lie
    origin = (inverse(cell_to_metric(ch.resolution, ch.origin)) @ np.array([0.0, 0.0, 1.0]))[:2]
    pivot = origin - np.array(ch.offset, np.float64)
    found = covariance.search(cache.derived('costfield', pa, _cost_field), wall_points_of(ch), A0, half,
                              min(math.degrees(tol_a), PRIOR_SEARCH_AT_MOST[1]), pivot)
    if found is None:
        return None
    A = refined(config, pa, ch, found[0]) if config.refine else found[0]
    inl = int(matching.inlier_mask(A, src, dst, config.ransac_threshold ** 2).sum()) if src.shape[0] else 0
    h = PairResult(A, matches=matches, inliers=inl, inlier_ratio=inl / float(max(1, matches)))
    h.agreement, h.overlap = verify.agreement(pa.levels, ch.levels, A, config.agreement_tolerance,
                                              (known_of(pa)[0], known_of(ch)[0]),
                                              walls_of(pa, config.agreement_tolerance))
    _judge(config, pa, ch, h)
    return h


def _align_crops(config: MergeConfig, pa: PairInput, ch: PairInput, seed: int) -> PairResult:
    """:func:`align_pair` between the crops' cells: the features' best hypothesis, or, when
    none is accepted and both robots have priors, the link found near the priors
    (:func:`_near_prior`) if that one is accepted."""
    r, src, dst = _align_features(config, pa, ch, seed)
    if r.accepted:
        return r
    h = _near_prior(config, pa, ch, src, dst, r.matches)
    return h if h is not None and h.accepted else r


def _align_features(config: MergeConfig, pa: PairInput, ch: PairInput,
                    seed: int) -> Tuple[PairResult, np.ndarray, np.ndarray]:
    """(the features' best hypothesis, the unique matches' (N, 2) child and parent cells)."""
    c = config
    fa, fc = at_one_scale(c, pa, ch)
    src, dst, unique = matching.match(fc, fa, c.match_candidates, c.match_ratio)
    r = PairResult(None, matches=int(unique.sum()))
    usrc, udst = src[unique], dst[unique]
    if src.shape[0] < c.min_matches:
        r.reason = 'too few matches (%d < %d)' % (src.shape[0], c.min_matches)
        return r, usrc, udst
    hyps = matching.ransac_rigid(src, dst, c.ransac_threshold, c.ransac_iterations, seed,
                            c.ransac_hypotheses, min_count=max(2, int(0.7 * c.min_inliers)))
    lv_a, lv_b = pa.levels, ch.levels
    boxes = (known_of(pa)[0], known_of(ch)[0])
    walls = walls_of(pa, c.agreement_tolerance)

    def verified(A: np.ndarray) -> Tuple[float, int]:
        # (agreement, overlap) on the crops, the parent's walls and both known boxes derived once
        return verify.agreement(lv_a, lv_b, A, c.agreement_tolerance, boxes, walls)

    # Score every hypothesis on the grids first (cheap), then polish only the promising ones
    # by ICP (the costly step) and score them again.
    scored = []
    for A, mask in hyps:
        inl = int(mask.sum())
        if inl < c.min_inliers:
            continue
        ag, _ = verified(A)
        scored.append((ag, inl, A))
    scored.sort(key=lambda t: (t[0], t[1]), reverse=True)
    best: Optional[PairResult] = None
    th2 = c.ransac_threshold ** 2
    tried = []
    centre = known_of(ch)[1]
    for rank, (ag, inl, A) in enumerate(scored):
        h = PairResult(A, matches=r.matches, inliers=inl)
        # the runner-up is polished only when it scores nearly as well as the best (it may be
        # the right one); so is any clearly different placement that might make the best one
        # ambiguous
        close = (rank == 0 or (rank == 1 and ag >= scored[0][0] - 0.05)
                 or (ag >= scored[0][0] - c.ambiguity_margin and centre is not None
                     and not _same_place(A, scored[0][2], centre, pa.resolution)))
        if c.refine and close and ag >= c.min_agreement - 0.2:
            h.A = refined(c, pa, ch, A)
        good_inl = int(matching.inlier_mask(h.A, usrc, udst, th2).sum()) if r.matches else 0
        h.inlier_ratio = good_inl / float(max(1, r.matches))
        h.agreement, h.overlap = verified(h.A)
        _judge(c, pa, ch, h)
        tried.append(h)
        # The grids decide between hypotheses: the best-agreeing accepted one wins.
        if best is None or (h.accepted, h.agreement, h.inliers) > (best.accepted, best.agreement, best.inliers):
            best = h
    if best is not None and best.accepted and centre is not None:
        _check_ambiguity(c, pa, best, tried, centre)
    if best is None and hyps:
        r.inliers = max(int(m.sum()) for _, m in hyps)
        r.reason = 'too few inliers (%d < %d)' % (r.inliers, c.min_inliers)
        return r, usrc, udst
    if best is None:
        r.reason = 'RANSAC found no consistent transform'
        return r, usrc, udst
    return best, usrc, udst


def _apart(A: np.ndarray, B: np.ndarray, centre: np.ndarray, resolution: float) -> Tuple[float, float]:
    """(metres, radians) between where two transforms put the child's centre, and its turn."""
    d = float(np.hypot(*(apply(A, centre) - apply(B, centre))[0])) * resolution
    return d, turn_between(A, B)


def _same_place(A: np.ndarray, B: np.ndarray, centre: np.ndarray, resolution: float) -> bool:
    d, da = _apart(A, B, centre, resolution)
    return within_tolerance(d, da, AMBIGUITY_APART)


def _check_ambiguity(config: MergeConfig, pa: PairInput, best: PairResult, tried,
                     centre: np.ndarray) -> None:
    """Reject ``best`` when another, clearly different placement of the child also passes every
    gate and agrees nearly as well (within ``ambiguity_margin``): the child looks alike in two
    places of the parent (a building of identical halves, seen whole by the parent), and the
    grids cannot say which. The runner-up is kept in ``best.runner_up`` (agreement,
    metres and degrees apart)."""
    rival = None
    for h in tried:
        if h is best or not h.accepted or _same_place(h.A, best.A, centre, pa.resolution):
            continue          # (the same placement, found twice)
        if rival is None or h.agreement > rival[0]:
            d, da = _apart(h.A, best.A, centre, pa.resolution)
            rival = (h.agreement, d, math.degrees(da))
    if rival is None:
        return
    best.runner_up = rival
    if config.ambiguity_margin > 0 and rival[0] >= best.agreement - config.ambiguity_margin:
        best.accepted = False
        best.reason = ('ambiguous: a second placement %.2f m, %.0f deg away also verifies (agreement '
                       '%.3f vs %.3f): the map looks alike in both places' % (rival[1], rival[2], rival[0],
                                                                             best.agreement))
