"""The caches of ``make accuracy`` (and ``make bend-sweep``): keys, the robots' bags and what
they hold (a digest of their messages), the SLAM runs' results found by that content (gmapping's of
the old scheme, keyed by the bags' key, moved over). Unit-tested in
test/unit/bench/test_accuracy_cache.py."""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import struct
import tempfile
import threading
import time
from typing import Any, Callable, Dict, List, Optional, Tuple

from accuracy_common import SLAMS, child_env, run_timed

# ------------------------------------------------------------------------------ cache keys

def file_digest(path: str) -> str:
    h = hashlib.sha1()
    with open(path, 'rb') as f:
        for chunk in iter(lambda: f.read(1 << 20), b''):
            h.update(chunk)
    return h.hexdigest()


def world_digest(yaml_path: str) -> str:
    import yaml
    with open(yaml_path) as f:
        meta = yaml.safe_load(f)
    img = meta['image'] if os.path.isabs(meta['image']) else os.path.join(os.path.dirname(yaml_path), meta['image'])
    return hashlib.sha1((file_digest(yaml_path) + file_digest(img)).encode()).hexdigest()


def key_of(doc: Dict[str, Any]) -> str:
    return hashlib.sha1(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:10]



def read_json(path: str) -> Optional[Any]:
    """The JSON document in ``path``, None when it is absent or unreadable."""
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def write_json(path: str, doc: Any) -> None:
    """``doc`` into ``path`` at once (a file of this process and thread, then renamed): a reader
    sees the whole file or none."""
    tmp = '%s.tmp-%d-%d' % (path, os.getpid(), threading.get_ident())
    with open(tmp, 'w') as f:
        json.dump(doc, f, indent=1)
    os.replace(tmp, path)


def cached_bags(d: str) -> Optional[Dict[str, Any]]:
    """What ``make_bags_dir`` recorded of the bags in ``d`` (its ok.json), None when not made.
    ``make_bags_dir`` writes into a directory of its own and renames it to ``d`` only once the
    bags are made and ok.json is written, so a ``d`` whose bags are being written or whose make
    failed does not exist (or has no ok.json): None."""
    done = read_json(os.path.join(d, 'ok.json'))
    return done if isinstance(done, dict) else None


def make_bags_dir(d: str, doc: Dict[str, Any], cmd_for: Callable[[str], List[str]],
                  timeout: float = 3600) -> Dict[str, Any]:
    """Run ``make_robot_bags`` (``cmd_for(directory)``: its command writing team.bag there) into
    a directory of its own (``d``.tmp-XXXX: two runs making the same bags do not share one),
    record ``doc`` (args.json) and its times (ok.json), then rename it to ``d``: {'wall_s',
    'cpu_s'}. When another run made ``d`` meanwhile, its bags are kept and this copy dropped; an
    incomplete ``d`` (no ok.json) is set aside (``d``.incomplete-TIME), not deleted. Raises
    RuntimeError with the log's tail when it fails (its directory is left for the log)."""
    parent = os.path.dirname(d)
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=os.path.basename(d) + '.tmp-', dir=parent)
    os.chmod(tmp, 0o755)
    r = run_timed(cmd_for(tmp), os.path.join(tmp, 'make_robot_bags.log'), child_env(), timeout)
    if r['rc'] != 0 or not os.path.exists(os.path.join(tmp, 'team.truth.yaml')):
        with open(os.path.join(tmp, 'make_robot_bags.log')) as f:
            tail = f.read()[-600:]
        raise RuntimeError('make_robot_bags failed (exit %s, in %s): %s' % (r['rc'], tmp, tail))
    with open(os.path.join(tmp, 'args.json'), 'w') as f:
        json.dump(doc, f, indent=1)
    with open(os.path.join(tmp, 'ok.json'), 'w') as f:
        json.dump({'wall_s': r['wall_s'], 'cpu_s': r['cpu_s']}, f)
    if os.path.exists(d) and cached_bags(d) is None:
        os.replace(d, '%s.incomplete-%s' % (d, time.strftime('%Y%m%dT%H%M%S')))
    try:
        os.replace(tmp, d)
    except OSError:
        if cached_bags(d) is None:
            raise
        shutil.rmtree(tmp, ignore_errors=True)   # another run made these bags first: its copy is kept
    return r


# ------------------------------------------------------------------------------ a bag's content

CONTENT_FILE = 'content.json'
BAG_FILES = ('team.bag', 'team_single.bag')
_content_lock = threading.Lock()


def bag_content_digest(path: str) -> Dict[str, Any]:
    """The digest of what ``path`` (a bag) holds, not of its file: sha1 over every message, in the
    order ``read_messages`` gives them, of its topic, its receive time (ns), its type (name and
    md5) and its serialised bytes (``raw=True``: not deserialised). The file's own layout (chunk
    size, compression, index, when it was written) does not change it. {'sha1', 'messages',
    'seconds'} (the time the digest took)."""
    import rosbag
    t0 = time.time()
    h = hashlib.sha1()
    n = 0
    with rosbag.Bag(path) as b:
        for topic, raw, t in b.read_messages(raw=True):
            datatype, data, md5sum = raw[0], raw[1], raw[2]
            head = '%s\0%s\0%s\0' % (topic, datatype, md5sum)
            h.update(head.encode())
            h.update(struct.pack('<qQ', t.to_nsec(), len(data)))
            h.update(data)
            n += 1
    return {'sha1': h.hexdigest(), 'messages': n, 'seconds': round(time.time() - t0, 2)}


def _stat_of(path: str) -> List[int]:
    st = os.stat(path)
    return [st.st_size, st.st_mtime_ns]


def bag_contents(d: str, names: Tuple[str, ...] = BAG_FILES,
                 digest: Callable[[str], Dict[str, Any]] = bag_content_digest,
                 log: Optional[Callable[[str], None]] = None) -> Optional[Dict[str, Dict[str, Any]]]:
    """The content digests of the bags ``names`` of the bag directory ``d`` (``bag_content_digest``):
    {name: {'sha1', 'messages', 'seconds', 'stat'}}, kept in ``d``/content.json. A digest is made
    once per bag, when it is missing there or the bag's file changed since (its size and mtime,
    'stat'), and ``log`` is told how long it took. None for a directory whose bags are not
    complete (no ok.json: being made, or their make failed): its bags are not read."""
    if cached_bags(d) is None:
        return None
    with _content_lock:                    # one digest of a bag at a time, also across a condition's threads
        path = os.path.join(d, CONTENT_FILE)
        doc = read_json(path)
        doc = doc if isinstance(doc, dict) else {}
        made = []
        for name in names:
            bag = os.path.join(d, name)
            if not os.path.exists(bag):
                continue
            have = doc.get(name)
            if isinstance(have, dict) and have.get('sha1') and have.get('stat') == _stat_of(bag):
                continue
            got = dict(digest(bag))
            got['stat'] = _stat_of(bag)
            doc[name] = got
            made.append(name)
        if made:
            write_json(path, doc)
            if log is not None:
                log('bag contents digested (%s): %s' % (path, ', '.join(
                    '%s %d messages in %.1f s' % (n, doc[n].get('messages', -1), doc[n].get('seconds', float('nan')))
                    for n in made)))
        return {n: doc[n] for n in names if n in doc}


# ------------------------------------------------------------------------------ SLAM results by content
# (the functions keep gmapping's names: gmapping_dir, resolve_gmapping, run_gmapping's results)

GMAPPING_FILES = ('.yaml', '.pgm', '.log', '.core.log')


def slam_of(doc: Dict[str, Any]) -> str:
    """The SLAM a run's key document names; a document without 'slam' (written before rbpf_slam
    existed) is gmapping's."""
    return str(doc.get('slam', 'gmapping'))


def gmapping_dir(work: str, world: str, seed: int, content: str, slam: str = 'gmapping') -> str:
    """Where the runs of ``slam`` on a bag of this content (its sha1, ``bag_contents``) are kept:
    ``work``/CACHE/WORLD-sSEED-content-SHA1 (CACHE: ``gmapping`` or ``rbpf_slam``, SLAMS; SHA1 its
    first 12 hex digits; an old-scheme gmapping directory is named WORLD-sSEED-BAGKEY)."""
    return os.path.join(work, SLAMS[slam]['cache'], '%s-s%d-content-%s' % (world, seed, content[:12]))


def _same_run(args: Any, doc: Dict[str, Any]) -> bool:
    """``args`` (a result's key document) and ``doc`` name the same run but for its 'bag' (an
    old-scheme bag key there, a content digest here): the same SLAM (``slam_of``), robot, topic,
    seed, config and binary."""
    if not isinstance(args, dict):
        return False

    def run(d):
        out = {k: v for k, v in d.items() if k != 'bag'}
        out['slam'] = slam_of(d)
        return out
    return run(args) == run(doc)


def old_scheme_results(work: str, world: str, seed: int, robot: str, bag_file: str, content: str,
                       doc: Dict[str, Any], digest: Callable[[str], Dict[str, Any]] = bag_content_digest,
                       log: Optional[Callable[[str], None]] = None) -> List[Tuple[str, Dict[str, Any]]]:
    """The gmapping results of the OLD scheme (keyed by the bag key, the digest of the simulator's
    sources) that belong to this content: [(prefix, meta)], usable first. The rule: a result
    ``gmapping/WORLD-sSEED-BAGKEY/ROBOT.json`` whose key document's 'bag' is BAGKEY (the name of
    its directory), whose key is that document's, and whose run is this one but for the bag (robot,
    topic, seed, gmapping config and binary), was made from ``bags/WORLD-sSEED-BAGKEY/BAG_FILE``;
    it belongs to that bag's content (``bag_contents``: read only from a complete bag directory,
    digested once). A result whose bag directory is gone cannot be placed and is not used. Only
    gmapping has results of the old scheme (``doc``'s SLAM, ``slam_of``): for rbpf_slam, []."""
    if slam_of(doc) != 'gmapping':
        return []
    gm_root, bag_root = os.path.join(work, 'gmapping'), os.path.join(work, 'bags')
    if not os.path.isdir(gm_root):
        return []
    name_re = re.compile(r'^%s-s%d-([0-9a-f]{10})$' % (re.escape(world), seed))
    found = []
    for name in sorted(os.listdir(gm_root)):
        m = name_re.match(name)
        if not m:
            continue
        bag_key = m.group(1)
        prefix = os.path.join(gm_root, name, robot)
        meta = read_json(prefix + '.json')
        if not isinstance(meta, dict) or not isinstance(meta.get('args'), dict):
            continue
        args = meta['args']
        if args.get('bag') != bag_key or meta.get('key') != key_of(args) or not _same_run(args, doc):
            continue
        contents = bag_contents(os.path.join(bag_root, name), (bag_file,), digest, log)
        if not contents or contents.get(bag_file, {}).get('sha1') != content:
            continue
        found.append((prefix, meta))
    # a complete result first (a map saved), then the newest
    found.sort(key=lambda pm: (not pm[1].get('invalid') and os.path.exists(pm[0] + '.yaml'),
                               os.path.getmtime(pm[0] + '.json')), reverse=True)
    return found


def _set_aside(prefix: str, key: Any) -> None:
    """A stale result at ``prefix`` (another gmapping key: another config or binary) moved to
    ``stale-KEY/`` beside it rather than deleted."""
    aside = os.path.join(os.path.dirname(prefix), 'stale-%s' % key)
    os.makedirs(aside, exist_ok=True)
    for ext in ('.json',) + GMAPPING_FILES:
        if os.path.exists(prefix + ext):
            os.replace(prefix + ext, os.path.join(aside, os.path.basename(prefix) + ext))


def resolve_gmapping(work: str, world: str, seed: int, robot: str, bag_file: str, content: str,
                     doc: Dict[str, Any], digest: Callable[[str], Dict[str, Any]] = bag_content_digest,
                     log: Optional[Callable[[str], None]] = None) -> Tuple[str, Optional[Dict[str, Any]]]:
    """Where ``robot``'s SLAM run (gmapping's or rbpf_slam's: ``doc``'s 'slam', ``slam_of``) on the
    bag ``bag_file`` of this content (``doc``: its key document, 'bag' = ``content``) is kept, and
    its result when there is one: (prefix, meta or None: to be run). The key document names the
    SLAM and its binary, and each SLAM has a directory of its own: one SLAM's result is never
    taken for the other's. Looked for in the content's directory (``gmapping_dir``), then among the
    old scheme's results (``old_scheme_results``): one found there is copied into the content's
    directory with its key rewritten (the new key, 'migrated_from' naming where it came from), so
    that every bag directory of this content, the old-named ones and ones remade by new sources,
    finds this one result. Nothing is deleted: the old result stays where it was (a run of the old
    code still finds it) and a stale result in the content's directory is set aside."""
    key = key_of(doc)
    d = gmapping_dir(work, world, seed, content, slam_of(doc))
    os.makedirs(d, exist_ok=True)
    prefix = os.path.join(d, robot)
    meta = read_json(prefix + '.json')
    if isinstance(meta, dict) and meta.get('key') == key:
        meta.update(map=prefix + '.yaml', log=prefix + '.log', cached=True)
        return prefix, meta
    olds = old_scheme_results(work, world, seed, robot, bag_file, content, doc, digest, log)
    if os.path.exists(prefix + '.json'):
        _set_aside(prefix, meta.get('key') if isinstance(meta, dict) else 'unreadable')
    if not olds:
        return prefix, None
    old_prefix, old = olds[0]
    for ext in GMAPPING_FILES:
        if os.path.exists(old_prefix + ext):
            shutil.copy2(old_prefix + ext, prefix + ext)
    new = dict(old)
    new.pop('cached', None)
    new.update(key=key, args=doc, map=prefix + '.yaml', log=prefix + '.log',
               migrated_from={'meta': old_prefix + '.json', 'key': old.get('key'), 'bag_key': old['args'].get('bag')})
    write_json(prefix + '.json', new)        # last: its presence means the result is complete
    new['cached'] = True
    new['migrated_now'] = True
    return prefix, new


