"""Accepted transforms saved to a YAML file on change and read back at start.

What is saved are the verified pairwise links (edges) with their scores, and for people the
resulting placements. On reload the links are *restored, not trusted*: each is verified again
on the robots' grids when both maps have arrived, and dropped if it no longer agrees.
The file is written atomically (temporary file + rename), so a crash never leaves half a file.
"""
from __future__ import annotations

import os
import tempfile
from typing import Any, Dict

import yaml


def save_state(path: str, state: Dict[str, Any]) -> None:
    """Write ``state`` to ``path`` atomically."""
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix='.transforms-', suffix='.yaml', dir=d)
    try:
        with os.fdopen(fd, 'w') as f:
            yaml.safe_dump(state, f, sort_keys=False)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def load_state(path: str) -> Dict[str, Any]:
    """Read a state file; {} when it does not exist. Raises ValueError when it is not valid."""
    if not os.path.exists(path):
        return {}
    try:
        with open(path) as f:
            data = yaml.safe_load(f) or {}
    except (OSError, yaml.YAMLError) as e:
        raise ValueError('%s: cannot read transforms file: %s' % (path, e)) from None
    if not isinstance(data, dict) or not isinstance(data.get('edges', []), list):
        raise ValueError('%s: not a multi_map_merge transforms file' % path)
    return data
