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

from .transforms import se2, wrap_angle, xyyaw

Link = Tuple[str, str, np.ndarray, float]   # (a, b, Z_ab 3x3, weight)


def link_errors(poses: Dict[str, np.ndarray], links: List[Link]) -> np.ndarray:
    """Every link's error (E, 3: x, y in metres, yaw in radians) at ``poses``: what the poses
    say b sits at, in ``Z``'s frame (zero where they agree with the link); its frames must be
    in ``poses``."""
    return _errors(*_arrays(sorted(poses), poses, links))


def _arrays(order: List[str], poses: Dict[str, np.ndarray], links: List[Link]):
    """(P: (x, y, yaw) of each frame of ``order``, ia / ib: each link's frames' rows of P, Zp:
    each link's (x, y, yaw))."""
    idx = {n: i for i, n in enumerate(order)}
    P = np.array([xyyaw(poses[n]) for n in order], float).reshape(-1, 3)
    ia = np.array([idx[a] for a, _, _, _ in links], int)
    ib = np.array([idx[b] for _, b, _, _ in links], int)
    Zp = np.array([xyyaw(Z) for _, _, Z, _ in links], float).reshape(-1, 3)
    return P, ia, ib, Zp


def optimise(poses: Dict[str, np.ndarray], links: List[Link], fixed: str,
             sigma_xy: float = 0.05, sigma_yaw: float = math.radians(0.5),
             iterations: int = 20, covs: Optional[List[Optional[np.ndarray]]] = None) -> Dict[str, np.ndarray]:
    """Poses (3x3, merged frame) of every frame in ``poses`` (the initial guesses) adjusted
    to all ``links`` between them; ``fixed`` keeps its pose. Links to unknown frames are
    ignored. Gauss-Newton with the analytic Jacobians of the error
    ``e_xy = Rz^T (Ra^T (tb - ta) - tz)``, ``e_yaw = yaw_b - yaw_a - yaw_z``, all links at once.

    ``covs``: per link, the 3x3 covariance of (x, y, yaw) of its ``Z`` (x, y in ``a``'s frame)
    or None; a link with one is weighed by its information matrix instead of its weight and
    the sigmas (a link through a corridor then pins its robot across it, not along it); a
    link without one among them counts as ``sigma_xy``, ``sigma_yaw``, unweighted, as in
    :func:`covariances` (its walls said too little to pin it: its inliers must not weigh it
    above the links they pinned)."""
    names = [n for n in sorted(poses) if n != fixed]
    keep = [lk[0] in poses and lk[1] in poses and lk[0] != lk[1] for lk in links]
    covs = [c for c, k in zip(covs, keep) if k] if covs is not None else None
    if covs is not None and any(c is not None for c in covs):
        fallback = np.diag([sigma_xy ** 2, sigma_xy ** 2, sigma_yaw ** 2])
        covs = [fallback if c is None else c for c in covs]
    links = [lk for lk, k in zip(links, keep) if k]
    if not names or len(links) < len(names) + 1:     # a tree: nothing to average
        return dict(poses)
    # (frame 0 is the fixed one: frame i > 0 has column block i-1)
    P, ia, ib, Zp = _arrays([fixed] + names, poses, links)
    w = np.sqrt(np.array([lk[3] for lk in links], float))
    N = len(names)
    whiten = _whitening(Zp, covs, w, sigma_xy, sigma_yaw)
    for _ in range(iterations):
        r = np.einsum('eij,ej->ei', whiten, _errors(P, ia, ib, Zp))
        Ja, Jb = _jacobians(P, ia, ib, Zp, whiten)
        H, g = _normal_equations(Ja, Jb, ia, ib, N, r)
        dxv = -np.linalg.solve(H + 1e-9 * np.eye(3 * N), g)
        P[1:] += dxv.reshape(N, 3)
        P[1:, 2] = wrap_angle(P[1:, 2])
        if np.max(np.abs(dxv)) < 1e-8:
            break
    out = dict(poses)
    for i, n in enumerate(names, 1):
        out[n] = se2(*P[i])
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
    C = np.array([np.asarray(c, float) for c in covs if c is not None])
    cz, sz = np.cos(Zp[has, 2]), np.sin(Zp[has, 2])
    Q = np.zeros((len(C), 3, 3))
    Q[:, 0, 0], Q[:, 0, 1], Q[:, 1, 0], Q[:, 1, 1], Q[:, 2, 2] = cz, sz, -sz, cz, 1.0
    info = np.linalg.inv(Q @ C @ Q.transpose(0, 2, 1))
    L[has] = np.linalg.cholesky(0.5 * (info + info.transpose(0, 2, 1))).transpose(0, 2, 1)   # upper: L^T L = info
    return L, has


def _whitening(Zp: np.ndarray, covs: Optional[List[Optional[np.ndarray]]], w: np.ndarray,
               sigma_xy: float, sigma_yaw: float) -> np.ndarray:
    """Per link (E, 3, 3) the matrix that whitens its error: its square-root information
    (:func:`_sqrt_information`) where it has a covariance, else its weight's square root ``w``
    over the sigmas."""
    out = np.zeros((len(Zp), 3, 3))
    out[:, 0, 0] = out[:, 1, 1] = w / sigma_xy
    out[:, 2, 2] = w / sigma_yaw
    L, has = _sqrt_information(Zp, covs)
    if L is not None:
        out[has] = L[has]
    return out


def _errors(P: np.ndarray, ia: np.ndarray, ib: np.ndarray, Zp: np.ndarray) -> np.ndarray:
    """Every link's error (E, 3) at the poses ``P`` ((x, y, yaw) per frame): with ``Z`` the link,
    ``e_xy = Rz^T (Ra^T (tb - ta) - tz)``, ``e_yaw = yaw_b - yaw_a - yaw_z``."""
    ca, sa = np.cos(P[ia, 2]), np.sin(P[ia, 2])
    cz, sz = np.cos(Zp[:, 2]), np.sin(Zp[:, 2])
    dx, dy = P[ib, 0] - P[ia, 0], P[ib, 1] - P[ia, 1]
    ux, uy = ca * dx + sa * dy - Zp[:, 0], -sa * dx + ca * dy - Zp[:, 1]      # Ra^T (tb - ta) - tz
    return np.stack([cz * ux + sz * uy, -sz * ux + cz * uy, wrap_angle(P[ib, 2] - P[ia, 2] - Zp[:, 2])], 1)


def _jacobians(P: np.ndarray, ia: np.ndarray, ib: np.ndarray, Zp: np.ndarray,
               whiten: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """(d e / d pose_a, d e / d pose_b) per link (E, 3, 3 each), whitened: with Rz^T Ra^T = M,
    d(Ra^T d)/d(ta) = -Ra^T, /d(tb) = Ra^T, /d(yaw_a) = [[-sa, ca], [-ca, -sa]] d."""
    ca, sa = np.cos(P[ia, 2]), np.sin(P[ia, 2])
    cz, sz = np.cos(Zp[:, 2]), np.sin(Zp[:, 2])
    dx, dy = P[ib, 0] - P[ia, 0], P[ib, 1] - P[ia, 1]
    Rz_T = np.stack([np.stack([cz, sz], 1), np.stack([-sz, cz], 1)], 1)
    M = Rz_T @ np.stack([np.stack([ca, sa], 1), np.stack([-sa, ca], 1)], 1)
    dth = np.einsum('eij,ej->ei', Rz_T, np.stack([-sa * dx + ca * dy, -ca * dx - sa * dy], 1))
    Ja = np.zeros((len(Zp), 3, 3))
    Jb = np.zeros((len(Zp), 3, 3))
    Ja[:, :2, :2], Ja[:, :2, 2], Ja[:, 2, 2] = -M, dth, -1.0
    Jb[:, :2, :2], Jb[:, 2, 2] = M, 1.0
    return whiten @ Ja, whiten @ Jb


def _normal_equations(Ja: np.ndarray, Jb: np.ndarray, ia: np.ndarray, ib: np.ndarray, N: int,
                      r: Optional[np.ndarray] = None) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """(H = J^T J (3N x 3N), g = J^T r) over every link, from each link's two blocks (frame 0
    is the fixed one: it has no columns); g None without residuals ``r``. The blocks are summed
    by ``np.bincount`` (``np.add.at`` is unbuffered: many times slower), in the order the
    links come."""
    JaT, JbT = Ja.transpose(0, 2, 1), Jb.transpose(0, 2, 1)
    ab = JaT @ Jb
    M = N + 1
    cells = np.concatenate([ia * M + ia, ib * M + ib, ia * M + ib, ib * M + ia])
    blocks = np.concatenate([JaT @ Ja, JbT @ Jb, ab, ab.transpose(0, 2, 1)]).reshape(-1, 9)
    H = _sum_rows(cells, blocks, M * M).reshape(M, M, 3, 3)
    H = H.transpose(0, 2, 1, 3).reshape(3 * M, 3 * M)[3:, 3:]
    if r is None:
        return H, None
    g = _sum_rows(np.concatenate([ia, ib]), np.concatenate([np.einsum('eij,ej->ei', JaT, r),
                                                            np.einsum('eij,ej->ei', JbT, r)]), M)
    return H, g[1:].reshape(-1)


def _sum_rows(index: np.ndarray, rows: np.ndarray, n: int) -> np.ndarray:
    """(n, K): per index value, the sum of the ``rows`` (E, K) that carry it."""
    return np.stack([np.bincount(index, rows[:, k], n) for k in range(rows.shape[1])], 1)


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
    P, ia, ib, Zp = _arrays([fixed] + names, poses, links)
    L, _ = _sqrt_information(Zp, covs)
    N = len(names)
    H, _ = _normal_equations(*_jacobians(P, ia, ib, Zp, L), ia, ib, N)
    # frames with no path of links to the fixed one have no information: left out
    free = [i for i in range(N) if H[3 * i:3 * i + 3, 3 * i:3 * i + 3].diagonal().min() > 0]
    if not free:
        return {}
    sel = np.concatenate([np.arange(3 * i, 3 * i + 3) for i in free])
    Hs = H[np.ix_(sel, sel)]
    # (H is symmetric: its condition number from its eigenvalues, cheaper than cond's SVD)
    eig = np.linalg.eigvalsh(Hs)
    if eig[0] <= 0 or eig[-1] > 1e12 * eig[0]:
        return {}
    C = np.linalg.inv(Hs)
    return {names[i]: C[3 * k:3 * k + 3, 3 * k:3 * k + 3] for k, i in enumerate(free)}


def mahalanobis2(e: np.ndarray, Z: np.ndarray, C: np.ndarray) -> float:
    """Squared Mahalanobis distance of a link's error ``e`` (:func:`link_errors`) under the
    link's covariance ``C`` (of its ``Z``'s x, y, yaw; x, y in the link's parent frame)."""
    L, _ = _sqrt_information(np.array([xyyaw(Z)], float), [C])
    w = L[0] @ np.asarray(e, float)
    return float(w @ w)


def worst_residual(poses: Dict[str, np.ndarray], links: List[Link]) -> Optional[Tuple[float, float]]:
    """Largest (metres, radians) disagreement of a link with the poses (None without links)."""
    links = [lk for lk in links if lk[0] in poses and lk[1] in poses]
    if not links:
        return None
    e = link_errors(poses, links)
    return float(np.hypot(e[:, 0], e[:, 1]).max()), float(np.abs(e[:, 2]).max())
