"""One robot's latest map as the merger holds it: the grid as received and the grid at the
merger's working resolution. Below both the merger and its workers, which both handle it."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Dict, Tuple

from .grid import Grid, rescale


@dataclass
class RobotMap:
    """The latest grid of one robot. ``grid`` is at the merger's working resolution (the
    reference's): a map of another resolution is rescaled, not rejected."""

    name: str
    raw: Grid           # as received
    version: int
    received: float     # seconds (time.time()) when it arrived
    grid: Grid = None   # type: ignore[assignment]  # working-resolution grid, set by set_working_resolution()
    life: int = 0       # how often the robot was forgotten (map restarts) before this map
    # what was derived from the working grid, by what it is: (the key it was derived at, it)
    _memo: Dict[str, Tuple[tuple, Any]] = field(default_factory=dict, repr=False, compare=False)

    @property
    def key(self) -> tuple:
        """What anything derived from the working grid is cached under: (version, resolution)."""
        return self.version, self.grid.resolution

    def memo(self, what: str, make: Callable[[], Any]) -> Any:
        """``what`` derived from the working grid by ``make()``, once per :attr:`key`: the one
        cache of everything the merger and its workers derive from a map version."""
        cached = self._memo.get(what)
        if cached is None or cached[0] != self.key:
            cached = self._memo[what] = (self.key, make())
        return cached[1]

    def memo_ready(self, what: str) -> bool:
        """Whether ``what`` is derived for the current :attr:`key` already (:meth:`memo`)."""
        return self._memo.get(what, (None,))[0] == self.key

    def remember(self, what: str, value: Any) -> None:
        """Keep ``value``, derived elsewhere (a worker process), as ``what`` of this version."""
        self._memo[what] = (self.key, value)

    def rescaled(self, resolution: float) -> Grid:
        """The map at ``resolution`` (metres per cell), without keeping it: the working grid
        when it is at that resolution already, else the received grid rescaled."""
        if self.grid is None or abs(self.grid.resolution - resolution) > 1e-9:
            return rescale(self.raw, resolution)
        return self.grid

    def set_working_resolution(self, resolution: float) -> 'RobotMap':
        """Keep the map at ``resolution`` as its working grid (:meth:`rescaled`, rescaled only
        when the working grid is at another resolution); returns this map."""
        self.grid = self.rescaled(resolution)
        return self
