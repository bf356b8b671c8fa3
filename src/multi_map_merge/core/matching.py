"""Steps (2)-(3) (docs/design.md): match features, estimate a rigid transform by RANSAC, score it.

- Matching: brute force on Hamming distance, keeping each feature's two nearest neighbours
  as candidates, and neither a ratio test nor cross-check as a filter. Grid maps repeat
  themselves (alike corners, doors, corridors): the true partner of a feature is often the
  second nearest, and both filters throw exactly those matches away (docs/measurements.md).
  RANSAC's two-point rigid samples tolerate the extra outliers.
- RANSAC: rigid (rotation + translation, determinant +1; never a mirror, never a scale),
  from two-point samples, then a least-squares refit on the inliers.
- Reliability: the paper's inlier ratio ``N_inlier / (N_inlier + N_outlier)``, counted over
  the matches that pass Lowe's ratio test (0.8), so it keeps the paper's meaning and scale
  (unambiguous matches that agree with the transform); the ratio test only scores here.

Verification on the grids is :mod:`verify`'s.
"""
from __future__ import annotations

from typing import List, Tuple

import cv2
import numpy as np

from .features import Features
from .transforms import apply, rigid_fit_angle, rigid_fit_translation, turn_between, wrap_angle


def match(f_src: Features, f_dst: Features, candidates: int = 2,
          ratio: float = 0.8) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Brute-force Hamming matches of every source feature to its ``candidates`` nearest
    destination features.

    Returns (src points, dst points, ratio mask): (M, 2) float64 cell coordinates and a bool
    mask of the matches that pass Lowe's ratio test (nearest clearly better than the second).
    """
    if len(f_src) < 2 or len(f_dst) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, bool)
    k = min(max(2, candidates), len(f_dst))
    # batchDistance is BFMatcher's brute force returning arrays (the same neighbours, in the
    # same order), not one Python DMatch object per match
    dist, idx = cv2.batchDistance(f_src.descriptors, f_dst.descriptors, -1,
                                  normType=cv2.NORM_HAMMING, K=k)
    unique = dist[:, 0] < ratio * dist[:, 1]
    take = min(candidates, k)
    qi = np.repeat(np.arange(len(f_src)), take)
    ti = idx[:, :take].ravel()
    good = np.zeros((len(f_src), take), bool)
    good[:, 0] = unique
    return (f_src.points[qi].astype(np.float64), f_dst.points[ti].astype(np.float64),
            good.ravel())


def ransac_rigid(src: np.ndarray, dst: np.ndarray, threshold: float, iterations: int,
                 seed: int = 0, hypotheses: int = 1,
                 min_count: int = 2) -> List[Tuple[np.ndarray, np.ndarray]]:
    """Rigid RANSAC: up to ``hypotheses`` distinct transforms (3x3, dst ~ A src), best first,
    each refit by least squares on its inliers, with its inlier mask.

    Several are returned because on repetitive structure the hypothesis with the most inliers
    is often a wrong one and the right one is a close second; the grids decide between them.

    Args:
        src, dst: (N, 2) matched points, cells.
        threshold: inlier distance, cells.
        iterations: number of two-point hypotheses.
        seed: RNG seed, so the same maps give the same answer.
        min_count: hypotheses with fewer inliers are not worth refitting.
    """
    n = src.shape[0]
    if n < 2:
        return []
    rng = np.random.default_rng(seed)
    th2 = threshold * threshold
    # Preemptive scoring: every hypothesis on a fixed random subset of the matches, then only
    # the best few hundred on all of them (the ranking at the top is what matters).
    sub = rng.choice(n, 400, replace=False) if n > 400 else np.arange(n)
    terms = _match_terms(src, dst)
    terms_sub = terms[:, sub]
    # coordinates as separate contiguous arrays: the samples index them by the thousand
    px, py, qx, qy = (np.ascontiguousarray(v) for v in (src[:, 0], src[:, 1], dst[:, 0], dst[:, 1]))
    C, S, TX, TY, ANG, PRE = [], [], [], [], [], []
    drawn, batch = 0, 3000
    while drawn < iterations:
        m = min(batch, iterations - drawn)
        drawn += m
        i = rng.integers(0, n, m)
        j = rng.integers(0, n, m)
        dpx, dpy = px.take(j) - px.take(i), py.take(j) - py.take(i)
        dqx, dqy = qx.take(j) - qx.take(i), qy.take(j) - qy.take(i)
        lp = np.hypot(dpx, dpy)
        lq = np.hypot(dqx, dqy)
        # A rigid motion keeps lengths: a sample whose two lengths differ cannot be right.
        ok = np.flatnonzero((lp > 4 * threshold) & (np.abs(lp - lq) < threshold))
        if ok.size:
            i, j = i.take(ok), j.take(ok)
            ang = np.arctan2(dqy.take(ok), dqx.take(ok)) - np.arctan2(dpy.take(ok), dpx.take(ok))
            c, s_ = np.cos(ang), np.sin(ang)
            mpx, mpy = 0.5 * (px.take(i) + px.take(j)), 0.5 * (py.take(i) + py.take(j))
            mqx, mqy = 0.5 * (qx.take(i) + qx.take(j)), 0.5 * (qy.take(i) + qy.take(j))
            tx = mqx - (c * mpx - s_ * mpy)
            ty = mqy - (s_ * mpx + c * mpy)
            pre = np.empty(c.size, np.int64)
            hyp = _hypothesis_terms(c, s_, tx, ty)
            for k0 in range(0, c.size, 1024):  # chunks keep the (hypotheses x matches) block small
                pre[k0:k0 + 1024] = np.count_nonzero(hyp[k0:k0 + 1024] @ terms_sub < th2, axis=1)
            C.append(c), S.append(s_), TX.append(tx), TY.append(ty), ANG.append(ang), PRE.append(pre)
            # Stop early once another batch would find a better two-inlier sample with less
            # than 1% chance (RANSAC's usual bound, from the best inlier ratio so far).
            w = min(0.999, max(int(p.max()) for p in PRE) / float(sub.size))
            if w > 0 and drawn >= np.log(0.01) / np.log(1.0 - w * w) and drawn >= 2 * batch:
                break
    if not C:
        return []
    c, s, tx, ty, ang, pre = (np.concatenate(v) for v in (C, S, TX, TY, ANG, PRE))
    if sub.size < n:
        keep = np.argsort(-pre, kind='stable')[:300]
        counts = np.zeros(c.size, np.int64)
        counts[keep] = np.count_nonzero(_hypothesis_terms(c[keep], s[keep], tx[keep], ty[keep]) @ terms < th2, axis=1)
    else:
        counts = pre
    out: List[Tuple[np.ndarray, np.ndarray]] = []
    # Candidates best first; near-duplicates (same turn, centre of the matches landing within
    # a few cells) are dropped in one vectorised pass before any refit.
    order = np.argsort(-counts, kind='stable')[:50 * hypotheses]
    order = order[counts[order] >= max(2, min_count)]
    centre = src.mean(axis=0)
    cx = c[order] * centre[0] - s[order] * centre[1] + tx[order]
    cy = s[order] * centre[0] + c[order] * centre[1] + ty[order]
    an = ang[order]
    # Greedy suppression, best first: a chosen candidate suppresses every candidate that is
    # the same hypothesis (one vectorised row per chosen one, at most 2 * hypotheses rows).
    suppressed = np.zeros(order.size, bool)
    chosen: List[int] = []
    for k in range(order.size):
        if suppressed[k]:
            continue
        chosen.append(k)
        if len(chosen) >= 2 * hypotheses:
            break
        dang = np.abs(wrap_angle(an - an[k]))
        suppressed |= (np.hypot(cx - cx[k], cy - cy[k]) < 3 * threshold) & (dang < np.radians(3))
    refits = _refit_all(*(v[order[chosen]] for v in (c, s, tx, ty)), src, dst, terms, th2)
    for A, mask in refits:
        if any(_same(A, B, centre, threshold) for B, _ in out):
            continue
        out.append((A, mask))
        if len(out) >= hypotheses:
            break
    return out


def _refit_all(c: np.ndarray, s: np.ndarray, tx: np.ndarray, ty: np.ndarray, src: np.ndarray,
               dst: np.ndarray, terms: np.ndarray, th2: float) -> List[Tuple[np.ndarray, np.ndarray]]:
    """Least-squares rigid refit of K hypotheses (cos, sin, tx, ty; each (K,)) on their
    inliers until each one's inlier set settles (it stops where a refit would lose inliers),
    all K at once: one hypothesis at a time, the refits were a third of RANSAC's time.
    ``terms``: :func:`_match_terms` of (src, dst). Returns [(3x3, inlier mask)] in the
    hypotheses' order."""
    c, s, tx, ty = (np.array(v, np.float64) for v in (c, s, tx, ty))
    sx, sy, dx, dy = src[:, 0], src[:, 1], dst[:, 0], dst[:, 1]
    # the products the least-squares sums need, per match: (x, y) of both and the cross terms
    per_match = np.stack([sx, sy, dx, dy, sx * dx, sx * dy, sy * dx, sy * dy], axis=1)

    def inliers(k):
        return _hypothesis_terms(c[k], s[k], tx[k], ty[k]) @ terms < th2

    every = np.arange(c.size)
    mask = inliers(every)
    count = np.count_nonzero(mask, axis=1)
    active = np.ones(c.size, bool)
    for _ in range(5):
        active &= count >= 2
        k = np.flatnonzero(active)
        if not k.size:
            break
        n = count[k].astype(np.float64)
        ssx, ssy, sdx, sdy, sxdx, sxdy, sydx, sydy = (mask[k] @ per_match).T
        th = np.arctan2(*rigid_fit_angle(n, ssx, ssy, sdx, sdy, sxdx, sxdy, sydx, sydy))
        c2, s2 = np.cos(th), np.sin(th)
        tx2, ty2 = rigid_fit_translation(n, c2, s2, ssx, ssy, sdx, sdy)
        saved = c[k], s[k], tx[k], ty[k]
        c[k], s[k], tx[k], ty[k] = c2, s2, tx2, ty2
        m2 = inliers(k)
        n2 = np.count_nonzero(m2, axis=1)
        worse = n2 < count[k]
        # a refit that loses inliers is not taken: that hypothesis keeps its last fit
        for v, old in zip((c, s, tx, ty), saved):
            v[k[worse]] = old[worse]
        took = k[~worse]
        settled = (m2[~worse] == mask[took]).all(axis=1)
        mask[took], count[took] = m2[~worse], n2[~worse]
        active[k[worse]] = False
        active[took[settled]] = False
    return [(np.array([[c[i], -s[i], tx[i]], [s[i], c[i], ty[i]], [0, 0, 1.0]]), mask[i]) for i in every]


# Squared residuals |R p + t - q|^2 of K hypotheses over N matches as one (K, 8) @ (8, N)
# product, expanded as |p|^2 + |q|^2 + |t|^2 + 2 t.Rp - 2 q.Rp - 2 t.q: scoring thousands of
# hypotheses is then a matrix product instead of eight passes over a (K, N) block (4x faster).
# In float64 the expansion's rounding stays below 10^-7 cells^2 for coordinates under 10^4.

def _match_terms(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(8, N) per-match factors of the squared residual (src p -> dst q, cells)."""
    px, py, qx, qy = src[:, 0], src[:, 1], dst[:, 0], dst[:, 1]
    return np.stack([px * px + py * py + qx * qx + qy * qy, np.ones(px.size), px, py,
                     px * qx + py * qy, px * qy - py * qx, qx, qy]).astype(np.float64)


def _hypothesis_terms(c: np.ndarray, s: np.ndarray, tx: np.ndarray, ty: np.ndarray) -> np.ndarray:
    """(K, 8) per-hypothesis factors of the squared residual (rotation cos, sin; translation, cells)."""
    return np.stack([np.ones(c.size), tx * tx + ty * ty, 2 * (c * tx + s * ty), 2 * (c * ty - s * tx),
                     -2 * c, -2 * s, -2 * tx, -2 * ty], axis=1)


def _same(A: np.ndarray, B: np.ndarray, centre: np.ndarray, threshold: float) -> bool:
    """Two hypotheses that put the matches' centre within a few cells and turn alike."""
    d = apply(A, centre[None])[0] - apply(B, centre[None])[0]
    return bool(np.hypot(*d) < 3 * threshold and turn_between(A, B) < np.radians(3))


def inlier_mask(A: np.ndarray, src: np.ndarray, dst: np.ndarray, th2: float) -> np.ndarray:
    """The matches (src -> dst, cells) that ``A`` maps within sqrt(``th2``) cells."""
    e = apply(A, src) - dst
    return np.einsum('ij,ij->i', e, e) < th2
