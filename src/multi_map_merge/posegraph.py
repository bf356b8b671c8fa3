"""A small SE(2) pose graph: every robot's map frame placed by all its verified links at once.

A chain of links adds up each link's error (a degree on the first link tilts everything behind
it); with more links than robots (every pair is matched) the placements can be averaged over
every cycle instead. Each link ``a -> b`` measures ``Z_ab`` (pose of b's frame in a's frame);
we find the poses ``T_k`` (of each frame in the merged frame, the reference fixed at the
identity) that minimise ``sum_w || log(Z_ab^-1 T_a^-1 T_b) ||^2`` (x, y in metres scaled by
``sigma_xy``, yaw in radians by ``sigma_yaw``) by Gauss-Newton. N is a few robots to a few
dozen, so numerical Jacobians do.
"""
from __future__ import annotations

import math
from typing import Dict, List, Optional, Tuple

import numpy as np

from .transforms import se2, xyyaw

Link = Tuple[str, str, np.ndarray, float]   # (a, b, Z_ab 3x3, weight)


def _residual(Ta: np.ndarray, Tb: np.ndarray, Z: np.ndarray) -> np.ndarray:
    x, y, yaw = xyyaw(np.linalg.inv(Z) @ np.linalg.inv(Ta) @ Tb)
    return np.array([x, y, yaw])


def optimise(poses: Dict[str, np.ndarray], links: List[Link], fixed: str,
             sigma_xy: float = 0.05, sigma_yaw: float = math.radians(0.5),
             iterations: int = 20) -> Dict[str, np.ndarray]:
    """Poses (3x3, merged frame) of every frame in ``poses`` (the initial guesses) adjusted
    to all ``links`` between them; ``fixed`` keeps its pose. Links to unknown frames are
    ignored."""
    names = [n for n in sorted(poses) if n != fixed]
    links = [lk for lk in links if lk[0] in poses and lk[1] in poses and lk[0] != lk[1]]
    if not names or len(links) < len(names) + 1:     # a tree: nothing to average
        return dict(poses)
    idx = {n: i for i, n in enumerate(names)}
    x = np.array([xyyaw(poses[n]) for n in names], float).ravel()
    scale = np.array([1 / sigma_xy, 1 / sigma_xy, 1 / sigma_yaw])

    def pose_of(v, n):
        if n == fixed:
            return poses[fixed]
        i = idx[n]
        return se2(v[3 * i], v[3 * i + 1], v[3 * i + 2])

    def residuals(v):
        return np.concatenate([math.sqrt(w) * scale * _residual(pose_of(v, a), pose_of(v, b), Z)
                               for a, b, Z, w in links])

    eps = 1e-6
    for _ in range(iterations):
        r = residuals(x)
        J = np.empty((r.size, x.size))
        for j in range(x.size):
            d = np.zeros_like(x)
            d[j] = eps
            J[:, j] = (residuals(x + d) - r) / eps
        H = J.T @ J + 1e-9 * np.eye(x.size)
        dx = -np.linalg.solve(H, J.T @ r)
        x = x + dx
        if np.max(np.abs(dx)) < 1e-7:
            break
    out = dict(poses)
    for n in names:
        out[n] = pose_of(x, n)
    return out


def worst_residual(poses: Dict[str, np.ndarray], links: List[Link]) -> Optional[Tuple[float, float]]:
    """Largest (metres, radians) disagreement of a link with the poses (None without links)."""
    worst = None
    for a, b, Z, _ in links:
        if a in poses and b in poses:
            e = _residual(poses[a], poses[b], Z)
            cur = (math.hypot(e[0], e[1]), abs(e[2]))
            worst = cur if worst is None else (max(worst[0], cur[0]), max(worst[1], cur[1]))
    return worst
