"""The benchmarks' one results format: ``NAME.json`` (the figures, with ``provenance``) and a text
table ``NAME.txt`` (or ``.md``) whose first lines say the same provenance: the commit the tree was
at (and whether it had uncommitted changes), when, on what machine, and the configuration the run
was given (its arguments and settings). A figure without the commit and the configuration that
made it cannot be compared with another one.

    from results import write_json, write_text
    write_json(path, doc, config)      # doc + {'provenance': provenance(config)}
    write_text(path, lines, config)    # '# commit ...', '# configuration ...', then lines
"""
from __future__ import annotations

import json
import os
import subprocess
import time
from typing import Any, Callable, Dict, List, Optional, Sequence

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def commit(repo: str = REPO) -> Dict[str, Any]:
    """{'commit': the full hash of HEAD or None outside a git checkout, 'dirty': whether tracked
    files differ from it}."""
    def git(*args: str) -> Optional[str]:
        try:
            return subprocess.check_output(['git', '-C', repo] + list(args), stderr=subprocess.DEVNULL,
                                           universal_newlines=True).strip()
        except (OSError, subprocess.CalledProcessError):
            return None
    head = git('rev-parse', 'HEAD')
    status = git('status', '--porcelain', '--untracked-files=no') if head else None
    return {'commit': head, 'dirty': bool(status)}


def provenance(config: Dict[str, Any], repo: str = REPO) -> Dict[str, Any]:
    """What made a result: the commit (``commit``), the UTC time, the machine (processors, model)
    and ``config`` (the run's arguments and settings, JSON-able)."""
    out = commit(repo)
    out['date_utc'] = time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())
    out['nproc'] = os.cpu_count()
    try:
        with open('/proc/cpuinfo') as f:
            out['cpu'] = next((ln.split(':', 1)[1].strip() for ln in f if ln.startswith('model name')), None)
    except OSError:
        out['cpu'] = None
    out['config'] = config
    return out


def header(prov: Dict[str, Any], comment: str = '#') -> List[str]:
    """The first lines of a text table: the commit, when, the machine, the configuration."""
    c = prov.get('commit') or 'no git checkout'
    return ['%s commit %s%s, %s, %s processors (%s)' % (comment, c, ' with uncommitted changes' if prov.get('dirty')
                                                         else '', prov.get('date_utc'), prov.get('nproc'),
                                                         prov.get('cpu') or 'cpu unknown'),
            '%s configuration: %s' % (comment, json.dumps(prov.get('config'), sort_keys=True, default=str))]


def write_json(path: str, doc: Dict[str, Any], config: Dict[str, Any],
               default: Optional[Callable[[Any], Any]] = None, **dump_kw: Any) -> Dict[str, Any]:
    """``doc`` with its ``provenance`` into ``path`` (written whole, then renamed); returns the
    provenance."""
    prov = provenance(config)
    out = dict(doc)
    out['provenance'] = prov
    tmp = '%s.tmp-%d' % (path, os.getpid())
    with open(tmp, 'w') as f:
        json.dump(out, f, default=default, **(dump_kw or {'indent': 1}))
    os.replace(tmp, path)
    return prov


def write_text(path: str, lines: Sequence[str], config: Dict[str, Any], comment: str = '#') -> None:
    """The text table ``lines`` into ``path`` under its provenance's lines (``comment``: the
    lines' prefix, e.g. '#' for .txt, '>' for markdown)."""
    with open(path, 'w') as f:
        f.write('\n'.join(header(provenance(config), comment) + [''] + list(lines)) + '\n')
