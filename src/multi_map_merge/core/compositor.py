"""(5) The merged grid: every placed map warped into the merged frame (its *patch*) and
composited (:mod:`composite`). A patch is kept per robot until its map version, placement, the
merged lattice or its correction field (:mod:`deform`) changes; the merged grid until a patch
changes, so a compose in which nothing moved returns the grid it returned last."""
from __future__ import annotations

from typing import Dict, Mapping, Optional, Tuple

import numpy as np

from . import deform
from .composite import Lattice, Patch, composite, lattice_for, warp_patch
from .config import MergeConfig
from .grid import Grid
from .placement import Placement
from .robot_map import RobotMap
from .team import TeamListener


class Compositor(TeamListener):
    """The merged grid of a merger's maps and its caches (see the module's docstring)."""

    def __init__(self, config: MergeConfig):
        self.config = config
        # per robot (key, patch, its field: held so that no other field takes its id, of the key)
        self._patches: Dict[str, Tuple[tuple, Optional[Patch], Optional[deform.Field]]] = {}
        # the last compose's lattice and robots, patches and merged grid: its patches are held, so
        # that a new patch never takes the memory of one of them (they are compared by identity)
        self._merged: Optional[Tuple[tuple, list, Grid]] = None   # (lattice, robots), patches, grid

    def forget(self, name: Optional[str] = None) -> None:
        """Drop the patch of robot ``name`` (None: of every robot): it is warped again."""
        if name is None:
            self._patches.clear()
        else:
            self._patches.pop(name, None)

    def robot_forgotten(self, name: str, reference: bool) -> None:
        self.forget(None if reference else name)   # (the reference's map frame is the merged frame)

    def reference_moved(self, old: str, new: str, has_map: bool) -> None:
        self.forget()

    def reset(self) -> None:
        """Drop every patch and the last merged grid: the next compose warps every map again."""
        self._patches.clear()
        self._merged = None

    def compose(self, maps: Mapping[str, RobotMap], placements: Mapping[str, Placement],
                fields: Mapping[str, Tuple[int, deform.Field]], ref: str) -> Grid:
        """The merged grid, in the reference ``ref``'s map frame on its map's lattice, of the
        ``placements`` of ``maps``; a map with a correction field of ``fields`` (per robot: (the
        map version it was fitted to, the field)) is bent by it."""
        lattice = lattice_for(maps[ref].grid)
        patches = []
        for name, pl in sorted(placements.items()):
            m = maps.get(name)
            if m is not None:
                # (a field is used only with the placement and map it was fitted to)
                version, f = fields.get(name, (None, None))
                if f is not None and not (version == m.version and np.array_equal(f.T, pl.T)):
                    f = None
                patches.append(self._patch(m, pl.T, lattice, f))
        key = (lattice.key(), tuple(sorted(n for n in placements if n in maps)))
        last = self._merged
        if (last is not None and last[0] == key and len(last[1]) == len(patches)
                and all(a is b for a, b in zip(last[1], patches))):
            return last[2]           # nothing moved or changed: the same merged grid
        grid = composite(patches, lattice, self.config.merged_map_frame, self.config.max_cells)
        self._merged = (key, patches, grid)
        return grid

    def _patch(self, m: RobotMap, T: np.ndarray, lattice: Lattice,
               field: Optional[deform.Field] = None) -> Optional[Patch]:
        """Map ``m`` warped by ``T`` (3x3, its map frame in the merged frame), or by ``field``,
        onto ``lattice``: its known cells' values (None when it knows none)."""
        key = (m.version, T.tobytes(), lattice.key(), id(field) if field is not None else None)
        cached = self._patches.get(m.name)
        if cached is not None and cached[0] == key:
            return cached[1]
        c = self.config
        kv = m.grid.known_values(c.free_thresh, c.occupied_thresh)
        if kv is None:
            p = None
        elif field is not None:
            p = deform.warp_field_patch(kv[1], kv[0], m.grid.resolution, m.grid.origin, field, lattice, c.max_cells)
        else:
            p = warp_patch(kv[1], kv[0], m.grid.resolution, m.grid.origin, T, lattice, c.max_cells)
        self._patches[m.name] = (key, p, field)
        return p
