"""What a process derives from the maps it sees, kept for the next pair: a worker sees the same
maps again and again (a map takes part in N-1 pairs), so what is derived from a map is derived
once per map version in each process. :mod:`pair`'s functions stay plain functions of plain
data; the caches they use are these."""
from __future__ import annotations

from typing import Callable, Dict, Optional

_EXTRACTORS: Dict[tuple, object] = {}
_DERIVED: Dict[tuple, object] = {}
_DERIVED_OWNER: object = None


def extractor(key: tuple, make: Callable):
    """The feature extractor ``make(*key)``, made once per ``key`` in this process."""
    fe = _EXTRACTORS.get(key)
    if fe is None:
        fe = _EXTRACTORS[key] = make(*key)
    return fe


def derived(what: str, p, make):
    """``make(p)``, cached per (merger, robot, resolution) in this process for the map's latest
    version only: maps that grow all the time would otherwise leave every older version's wall
    masks here until the cache's bound. And for one merger only (the node has one): a process
    that served a merger before (a test, a benchmark's cold cycles, a merger made anew) would
    otherwise keep that merger's data until the bound. ``p`` is a :class:`pair.PairInput` (its
    owner, name, version and resolution are read)."""
    forget_other_versions(p.owner)
    key = (what, p.name, p.resolution)
    v = _DERIVED.get(key)
    if v is None or v[0] != p.version:
        if len(_DERIVED) > 256:
            _DERIVED.clear()
        _DERIVED.pop(key, None)   # the old version freed before the new one is made
        v = _DERIVED[key] = (p.version, make(p))
    return v[1]


def forget_other_versions(owner: str, name: Optional[str] = None, version: Optional[int] = None) -> None:
    """Drop the derived data of every merger but ``owner``, and of ``name``'s map in versions
    other than ``version``."""
    global _DERIVED_OWNER
    if owner != _DERIVED_OWNER:
        _DERIVED.clear()
        _DERIVED_OWNER = owner
    elif name is not None:
        for key in [k for k, v in _DERIVED.items() if k[1] == name and v[0] != version]:
            del _DERIVED[key]

