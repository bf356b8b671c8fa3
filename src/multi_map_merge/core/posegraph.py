"""A small SE(2) pose graph: every robot's map frame placed by all its verified links at once.

A chain of links adds up each link's error (a degree on the first link tilts everything behind
it); with more links than robots (every pair is matched) the placements can be averaged over
every cycle instead. Each link ``a -> b`` measures ``Z_ab`` (pose of b's frame in a's frame);
we find the poses ``T_k`` (of each frame in the merged frame, the reference fixed at the
identity) that minimise ``sum_w || log(Z_ab^-1 T_a^-1 T_b) ||^2`` (x, y in metres scaled by
``sigma_xy``, yaw in radians by ``sigma_yaw``; or, for a link with a covariance, whitened by
its information) by Gauss-Newton with analytic Jacobians (32 robots, 496 links: a few ms).
:func:`covariances` gives the placements' covariance at the solution.
"""
from __future__ import annotations

import math
from typing import Dict, List, Optional, Tuple

import numpy as np

from .transforms import inverse, se2, wrap_angle, xyyaw

Link = Tuple[str, str, np.ndarray, float]   # (a, b, Z_ab 3x3, weight)


def link_error(Ta: np.ndarray, Tb: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """A link's error (x, y in metres, yaw in radians) at poses ``Ta``, ``Tb``: what the poses
    say b sits at, in ``Z``'s frame (zero where they agree with the link)."""
    x, y, yaw = xyyaw(inverse(Z) @ inverse(Ta) @ Tb)
    return np.array([x, y, yaw])


def optimise(poses: Dict[str, np.ndarray], links: List[Link], fixed: str,
             sigma_xy: float = 0.05, sigma_yaw: float = math.radians(0.5),
             iterations: int = 20, covs: Optional[List[Optional[np.ndarray]]] = None) -> Dict[str, np.ndarray]:
    """Poses (3x3, merged frame) of every frame in ``poses`` (the initial guesses) adjusted
    to all ``links`` between them; ``fixed`` keeps its pose. Links to unknown frames are
    ignored. Gauss-Newton with the analytic Jacobians of the error
    ``e_xy = Rz^T (Ra^T (tb - ta) - tz)``, ``e_yaw = yaw_b - yaw_a - yaw_z``, all links at once.

    ``covs``: per link, the 3x3 covariance of (x, y, yaw) of its ``Z`` (x, y in ``a``'s frame)
    or None; a link with one is weighed by its information matrix instead of its weight and
    the sigmas (a link through a corridor then pins its robot across it, not along it)."""
    names = [n for n in sorted(poses) if n != fixed]
    keep = [lk[0] in poses and lk[1] in poses and lk[0] != lk[1] for lk in links]
    covs = [c for c, k in zip(covs, keep) if k] if covs is not None else None
    links = [lk for lk, k in zip(links, keep) if k]
    if not names or len(links) < len(names) + 1:     # a tree: nothing to average
        return dict(poses)
    order = [fixed] + names
    idx = {n: i for i, n in enumerate(order)}          # column block i-1; the fixed one has none
    P = np.array([xyyaw(poses[n]) for n in order], float)
    ia = np.array([idx[a] for a, _, _, _ in links])
    ib = np.array([idx[b] for _, b, _, _ in links])
    Zp = np.array([xyyaw(Z) for _, _, Z, _ in links], float)
    w = np.sqrt(np.array([lk[3] for lk in links], float))
    cz, sz = np.cos(Zp[:, 2]), np.sin(Zp[:, 2])
    E, N = len(links), len(names)
    sqrt_info, has = _sqrt_information(Zp, covs)
    for _ in range(iterations):
        ta, tb = P[ia, :2], P[ib, :2]
        ca, sa = np.cos(P[ia, 2]), np.sin(P[ia, 2])
        dx, dy = tb[:, 0] - ta[:, 0], tb[:, 1] - ta[:, 1]
        lx, ly = ca * dx + sa * dy, -sa * dx + ca * dy            # Ra^T (tb - ta)
        ux, uy = lx - Zp[:, 0], ly - Zp[:, 1]
        ex, ey = cz * ux + sz * uy, -sz * ux + cz * uy            # Rz^T (...)
        eth = wrap_angle(P[ib, 2] - P[ia, 2] - Zp[:, 2])
        r_raw = np.stack([ex, ey, eth], 1)
        r = np.stack([ex / sigma_xy, ey / sigma_xy, eth / sigma_yaw], 1) * w[:, None]
        # d(Ra^T d)/d(ta) = -Ra^T, /d(tb) = Ra^T, /d(yaw_a) = [[-sa, ca], [-ca, -sa]] d
        Ra_T = np.stack([np.stack([ca, sa], 1), np.stack([-sa, ca], 1)], 1)     # (E, 2, 2)
        Rz_T = np.stack([np.stack([cz, sz], 1), np.stack([-sz, cz], 1)], 1)
        M = np.einsum('eij,ejk->eik', Rz_T, Ra_T)                              # Rz^T Ra^T
        dth = np.stack([-sa * dx + ca * dy, -ca * dx - sa * dy], 1)           # dRa^T/dyaw d
        dth = np.einsum('eij,ej->ei', Rz_T, dth)
        J = np.zeros((E, 3, 3 * N))
        J_raw = J                                   # (the unscaled Jacobian, filled below)
        scale = np.array([1 / sigma_xy, 1 / sigma_xy, 1 / sigma_yaw])[:, None] * 1.0
        for e_idx, (i_a, i_b) in enumerate(zip(ia, ib)):
            if i_a > 0:
                c = 3 * (i_a - 1)
                J[e_idx, :2, c:c + 2] = -M[e_idx]
                J[e_idx, :2, c + 2] = dth[e_idx]
                J[e_idx, 2, c + 2] = -1.0
            if i_b > 0:
                c = 3 * (i_b - 1)
                J[e_idx, :2, c:c + 2] = M[e_idx]
                J[e_idx, 2, c + 2] = 1.0
        J = J * scale[None] * w[:, None, None]
        if sqrt_info is not None:
            # links with a covariance: whitened by it (rows of the others as above)
            r[has] = np.einsum('eij,ej->ei', sqrt_info[has], r_raw[has])
            J[has] = np.einsum('eij,ejk->eik', sqrt_info[has], J_raw[has])
        J = J.reshape(3 * E, 3 * N)
        r = r.reshape(-1)
        H = J.T @ J + 1e-9 * np.eye(3 * N)
        dxv = -np.linalg.solve(H, J.T @ r)
        P[1:] += dxv.reshape(N, 3)
        P[1:, 2] = wrap_angle(P[1:, 2])
        if np.max(np.abs(dxv)) < 1e-8:
            break
    out = dict(poses)
    for n in names:
        out[n] = se2(*P[idx[n]])
    return out


def _sqrt_information(Zp: np.ndarray, covs: Optional[List[Optional[np.ndarray]]]):
    """(per link L (E, 3, 3) with L^T L the information of its error ``e`` (e_xy is in the
    frame of the link's child, Rz^T of the link's x, y: Cov(e) = Q C Q^T, Q = diag(Rz^T, 1)),
    mask of the links that have a covariance); (None, None) when none has."""
    if covs is None or all(c is None for c in covs):
        return None, None
    E = Zp.shape[0]
    L = np.zeros((E, 3, 3))
    has = np.array([c is not None for c in covs])
    for e, C in enumerate(covs):
        if C is None:
            continue
        cz, sz = math.cos(Zp[e, 2]), math.sin(Zp[e, 2])
        Q = np.array([[cz, sz, 0.0], [-sz, cz, 0.0], [0.0, 0.0, 1.0]])
        info = np.linalg.inv(Q @ np.asarray(C, float) @ Q.T)
        L[e] = np.linalg.cholesky(0.5 * (info + info.T)).T      # upper: L^T L = info
    return L, has


def covariances(poses: Dict[str, np.ndarray], links: List[Link], fixed: str,
                covs: List[Optional[np.ndarray]], sigma_xy: float = 0.05,
                sigma_yaw: float = math.radians(0.5)) -> Dict[str, np.ndarray]:
    """Covariance of (x, y, yaw) of every frame's pose in ``poses`` (merged frame; ``fixed``
    exact) given ``links`` with their covariances ``covs`` (a link without one counts as
    ``sigma_xy``, ``sigma_yaw``, unweighted): the inverse of the Gauss-Newton information at
    those poses. Along a chain (a tree) this is the links' covariances propagated along it;
    with cycles, every link's information combined. Frames that the links do not pin in every
    direction are left out."""
    names = [n for n in sorted(poses) if n != fixed]
    keep = [lk[0] in poses and lk[1] in poses and lk[0] != lk[1] for lk in links]
    links = [lk for lk, k in zip(links, keep) if k]
    fallback = np.diag([sigma_xy ** 2, sigma_xy ** 2, sigma_yaw ** 2])
    covs = [fallback if c is None else c for c, k in zip(covs, keep) if k]
    if not names or not links:
        return {}
    order = [fixed] + names
    idx = {n: i for i, n in enumerate(order)}
    P = np.array([xyyaw(poses[n]) for n in order], float)
    Zp = np.array([xyyaw(Z) for _, _, Z, _ in links], float)
    L, _ = _sqrt_information(Zp, covs)
    N = len(names)
    H = np.zeros((3 * N, 3 * N))
    for e, (a, b, _, _) in enumerate(links):
        ia, ib = idx[a], idx[b]
        cz, sz = math.cos(Zp[e, 2]), math.sin(Zp[e, 2])
        ca, sa = math.cos(P[ia, 2]), math.sin(P[ia, 2])
        dx, dy = P[ib, 0] - P[ia, 0], P[ib, 1] - P[ia, 1]
        Rz_T = np.array([[cz, sz], [-sz, cz]])
        M = Rz_T @ np.array([[ca, sa], [-sa, ca]])
        dth = Rz_T @ np.array([-sa * dx + ca * dy, -ca * dx - sa * dy])
        J = np.zeros((3, 3 * N))
        if ia > 0:
            c = 3 * (ia - 1)
            J[:2, c:c + 2] = -M
            J[:2, c + 2] = dth
            J[2, c + 2] = -1.0
        if ib > 0:
            c = 3 * (ib - 1)
            J[:2, c:c + 2] = M
            J[2, c + 2] = 1.0
        J = L[e] @ J
        H += J.T @ J
    # frames with no path of links to the fixed one have no information: left out
    free = [i for i in range(N) if H[3 * i:3 * i + 3, 3 * i:3 * i + 3].diagonal().min() > 0]
    sel = np.concatenate([np.arange(3 * i, 3 * i + 3) for i in free]) if free else np.zeros(0, int)
    Hs = H[np.ix_(sel, sel)]
    if not free or np.linalg.cond(Hs) > 1e12:
        return {}
    C = np.linalg.inv(Hs)
    return {names[i]: C[3 * k:3 * k + 3, 3 * k:3 * k + 3] for k, i in enumerate(free)}


def mahalanobis2(e: np.ndarray, Z: np.ndarray, C: np.ndarray) -> float:
    """Squared Mahalanobis distance of a link's error ``e`` (:func:`link_error`) under the
    link's covariance ``C`` (of its ``Z``'s x, y, yaw; x, y in the link's parent frame)."""
    L, _ = _sqrt_information(np.array([xyyaw(Z)], float), [C])
    w = L[0] @ np.asarray(e, float)
    return float(w @ w)


def worst_residual(poses: Dict[str, np.ndarray], links: List[Link]) -> Optional[Tuple[float, float]]:
    """Largest (metres, radians) disagreement of a link with the poses (None without links)."""
    worst = None
    for a, b, Z, _ in links:
        if a in poses and b in poses:
            e = link_error(poses[a], poses[b], Z)
            cur = (math.hypot(e[0], e[1]), abs(e[2]))
            worst = cur if worst is None else (max(worst[0], cur[0]), max(worst[1], cur[1]))
    return worst
