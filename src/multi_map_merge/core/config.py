"""One typed configuration for the whole merger and its node: :class:`MergeConfig`, whose fields,
types and defaults are the parameters of :mod:`.parameters` (declared there, nowhere else)."""
from __future__ import annotations

import dataclasses
from typing import Any, Callable, Dict, List, Optional

from . import parameters as _params


def _annotation(p: _params.Parameter) -> Any:
    return {'bool': bool, 'int': int, 'double': float, 'string': str, 'string list': List[str],
            'double list': List[float], 'dict': Dict[str, List[float]]}[p.kind]


def _field(p: _params.Parameter):
    if isinstance(p.default, (list, dict)):
        return dataclasses.field(default_factory=p.fresh_default)
    return dataclasses.field(default=p.default)


@classmethod
def _former_name_wins(cls, given: Dict[str, Any], old: str) -> bool:
    """Whether ``given`` (parameters by name) is read by the former name ``old`` of a renamed
    parameter (:attr:`RENAMED`): it is given, and the new name is absent or at its default."""
    return _params.former_name_wins(given, old)


@classmethod
def _from_dict(cls, d: Dict[str, Any], warn: Optional[Callable[[str], None]] = None):
    """Build from a mapping (name -> value, as config/map_merge.yaml has them) through the one
    resolver (:func:`.parameters.resolve_strictly`): values converted to each field's type;
    m-explore's names and former names read as the node reads them. A value out of range, of
    the wrong type, or a name no parameter has raises :class:`.parameters.ParameterError` (a
    ValueError) naming each; warnings (an alias overridden, a deprecated name) go to ``warn``."""
    res = _params.resolve_strictly(d)
    if warn is not None:
        for line in res.warnings:
            warn(line)
    return cls(**{p.name: res.values[p.name] for p in _params.config_parameters()})


def _to_dict(self) -> Dict[str, Any]:
    return dataclasses.asdict(self)


MergeConfig = dataclasses.make_dataclass(
    'MergeConfig',
    [(p.name, _annotation(p), _field(p)) for p in _params.config_parameters()],
    namespace={
        '__doc__': 'The merger\'s and the node\'s parameters (:data:`.parameters.MERGER`, '
                   ':data:`.parameters.NODE`): one field per parameter, its default the table\'s.',
        'RENAMED': _params.renamed(),   # old name -> new name (the old one is still read)
        'former_name_wins': _former_name_wins,
        'from_dict': _from_dict,
        'to_dict': _to_dict,
    })
MergeConfig.__module__ = __name__   # (pickled to the worker processes by this name)
