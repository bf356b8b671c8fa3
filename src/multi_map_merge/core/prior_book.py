"""The priors a merger uses, as they change while it runs (:mod:`priors` says what a prior is).

It holds the priors in use (``initial_poses`` as configured, with those given or cleared while
running), m-explore's ``init_pose_*`` as given while they may still be spawn poses in one frame
the maps share (:mod:`spawn`), and the *epoch*: how often a prior changed, so that an estimation
cycle begun under other priors is discarded (:meth:`cycle.Cycle.stale`).

What a changed prior does to the merge (its pairs estimated again, its contradicted links
dropped, the placements made from priors made again) is its owner's: the merger's ``apply``
callback, called under the merger's lock with the new priors.
"""
from __future__ import annotations

import math
import threading
from typing import Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from . import spawn
from .config import MergeConfig
from .grid import Grid
from .priors import PriorRefused, Priors, in_priors_frame

#: apply(priors, changed): the priors in use are now ``priors``; ``changed`` names the robot whose
#: prior changed (None: priors read as if configured, nothing to redo). Returns the events.
Apply = Callable[[Priors, Optional[str]], List[str]]


class PriorBook:
    """The priors in use, the spawn poses and the epoch (see the module's docstring)."""

    def __init__(self, config: MergeConfig, lock: threading.Lock, apply: Apply):
        self.config = config
        self._lock = lock          # the merger's: the priors change with what they gate
        self._apply = apply
        self.priors: Priors = {n: list(p) for n, p in config.initial_poses.items()}
        self.epoch = 0             # bumped when a prior changes: a cycle begun before is discarded
        # a prior's compound changes (read the priors, relate, set) one at a time; taken before _lock
        self._compound = threading.RLock()
        self._implicit_ref = ''    # the reference given [0, 0, 0] for priors in the merged frame
        # m-explore's init_pose_* as given (robot -> [x, y, yaw]) while they may still be spawn
        # poses in one frame the maps share (check_spawn_poses); once the grids say so, _spawn_shared
        self._spawn_poses: Dict[str, List[float]] = {}
        self._spawn_checked = None      # the grids the last check saw: (their ids, them)
        self._spawn_shared = False

    def current(self) -> Priors:
        """The priors in use, robot -> ``[x, y, yaw]`` (a copy)."""
        with self._lock:
            return dict(self.priors)

    def set(self, name: str, pose: Optional[Sequence[float]]) -> List[str]:
        """Set (``[x, y, yaw]`` in the priors' frame) or remove (None) ``name``'s prior; a new
        epoch. Returns what the merger dropped (``apply``)."""
        with self._lock:
            priors = dict(self.priors)
            if pose is None:
                priors.pop(name, None)
            else:
                priors[name] = [float(v) for v in pose]
            # a new object, not an update: the estimation thread may be reading the old one
            self.priors = priors
            self.epoch += 1
            return self._apply(priors, name)

    def set_in_merged_frame(self, name: str, T: np.ndarray, reference: Callable[[], str]) -> List[str]:
        """Give ``name`` the prior ``T`` (3x3, its map frame in the merged frame, the map frame of
        the reference robot ``reference()``), carried into the priors' frame (:func:`priors.in_priors_frame`: with no
        other prior given, the reference gets [0, 0, 0] until :meth:`clear` leaves it alone)."""
        with self._compound:
            ref = reference()
            pose, ref_too = in_priors_frame(name, T, ref, self.current())
            if ref_too:
                self._implicit_ref = ref
                self.set(ref, [0.0, 0.0, 0.0])
            return self.set(name, pose)

    def clear(self, name: str) -> bool:
        """Remove ``name``'s prior, and the reference's [0, 0, 0] given by
        :meth:`set_in_merged_frame` once it is the only prior left. False when it had none."""
        with self._compound:
            if name not in self.current():
                return False
            self.set(name, None)
            ref = self._implicit_ref
            if ref and set(self.current()) <= {ref}:
                self.set(ref, None)
                self._implicit_ref = ''
            return True

    def wants_init_pose(self, name: str) -> bool:
        """``known_init_poses``, and ``name`` has no prior yet."""
        return self.config.known_init_poses and name not in self.current()

    def add_init_pose(self, name: str, pose: Sequence[float]) -> bool:
        """m-explore's ``init_pose_*`` of ``name`` as its prior, or [0, 0, 0] once they are known
        to be spawn poses in one shared frame (then True). PriorRefused when not finite."""
        pose = [float(v) for v in pose]
        if not all(math.isfinite(v) for v in pose):
            raise PriorRefused('not finite %s' % pose)
        with self._compound:
            self._spawn_poses[name] = pose
            if self._spawn_shared:
                self.set(name, [0.0, 0.0, 0.0])
                return True
            with self._lock:
                # as if configured: read before the robot's maps are estimated, nothing to redo
                self.priors = dict(self.priors, **{name: pose})
                self._apply(self.priors, None)
        return False

    def check_spawn_poses(self, raw_maps: Callable[[], Mapping[str, Grid]]
                          ) -> Optional[Tuple[List[str], spawn.SharedFrame, List[str]]]:
        """Until decided, whether the priors from :meth:`add_init_pose` are spawn poses of robots
        whose maps (``raw_maps()``, under the lock: the grids as received) share one frame; when
        so, each such robot's prior becomes [0, 0, 0]: (those robots, the verdict, the links
        dropped); else None. Checked again only when the maps changed."""
        with self._compound:
            if self._spawn_shared or len(self._spawn_poses) < 2:
                return None
            given = self.current()
            with self._lock:
                team = raw_maps()
                grids = {r: team[r] for r, p in self._spawn_poses.items() if given.get(r) == p and r in team}
            priors = {r: self._spawn_poses[r] for r in grids}
            seen = tuple(sorted((r, id(g)) for r, g in grids.items()))
            if self._spawn_checked is not None and seen == self._spawn_checked[0]:
                return None
            self._spawn_checked = (seen, grids)   # (the grids held: no other grid takes their ids)
        verdict = spawn.spawn_poses_in_one_frame(self.config, grids, priors)
        if verdict is None:
            return None
        events = []
        with self._compound:
            self._spawn_shared = True
            # (robots whose maps have not come yet too: the set-up is one)
            given = self.current()
            changed = [r for r in sorted(self._spawn_poses) if given.get(r) == self._spawn_poses[r]]
            for r in changed:
                events += self.set(r, [0.0, 0.0, 0.0])
        return changed, verdict, events
