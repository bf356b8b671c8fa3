"""bench/accuracy_cache.py, the cache of `make accuracy`: a bag's content digest (its messages,
not its file), the gmapping results found by that content, the migration of results of the old
scheme (keyed by the bag key, the digest of the simulator's sources) and a bag directory that is
not complete left unused. No ROS master, no gmapping run; the digest of real bags needs rosbag (skipped without it)."""
import hashlib
import json
import os
import sys

import pytest

BENCH = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'bench')
sys.path.insert(0, os.path.abspath(BENCH))

import accuracy  # noqa: E402
import accuracy_cache as acc  # noqa: E402
import accuracy_slam  # noqa: E402

# ------------------------------------------------------------------------------ content digest


def _write_bag(path, msgs, **kw):
    import rosbag
    with rosbag.Bag(path, 'w', **kw) as b:
        for topic, msg, t in msgs:
            b.write(topic, msg, t)


def _messages(change=None):
    """Two topics, 400 messages; ``change``: (index, what) changes one of them."""
    import rospy
    from std_msgs.msg import Float64MultiArray, String
    out = []
    for i in range(400):
        t = rospy.Time(100, 0) + rospy.Duration(0.05 * (i // 2))   # two messages at every instant
        if i % 2:
            out.append(('/tb3_0/scan', Float64MultiArray(data=[float(i)] * 50), t))
        else:
            out.append(('/tb3_1/odom', String(data='message %d' % i), t))
    if change is not None:
        i, what = change
        topic, msg, t = out[i]
        if what == 'data':
            msg = String(data=msg.data + '!') if isinstance(msg, String) else Float64MultiArray(data=[0.5] * 50)
        elif what == 'time':
            t = t + rospy.Duration(0, 1)
        elif what == 'topic':
            topic = topic + '_x'
        out[i] = (topic, msg, t)
    return out


def test_content_digest_ignores_the_file_layout(tmp_path):
    pytest.importorskip('rosbag')
    import rosbag
    a, b, c = str(tmp_path / 'a.bag'), str(tmp_path / 'b.bag'), str(tmp_path / 'c.bag')
    _write_bag(a, _messages())
    _write_bag(b, _messages(), chunk_threshold=1024, compression=rosbag.Compression.BZ2)
    _write_bag(c, _messages(), chunk_threshold=4096, compression=rosbag.Compression.LZ4)
    with open(a, 'rb') as f1, open(b, 'rb') as f2, open(c, 'rb') as f3:
        assert len({f1.read(), f2.read(), f3.read()}) == 3       # three different files
    da, db, dc = (acc.bag_content_digest(p) for p in (a, b, c))
    assert da['messages'] == db['messages'] == dc['messages'] == 400
    assert da['sha1'] == db['sha1'] == dc['sha1']
    assert da['seconds'] >= 0


@pytest.mark.parametrize('change', [(0, 'data'), (399, 'data'), (200, 'time'), (57, 'topic')])
def test_a_changed_message_changes_the_content_digest(tmp_path, change):
    pytest.importorskip('rosbag')
    a, b = str(tmp_path / 'a.bag'), str(tmp_path / 'b.bag')
    _write_bag(a, _messages())
    _write_bag(b, _messages(change))
    assert acc.bag_content_digest(a)['sha1'] != acc.bag_content_digest(b)['sha1']


# ------------------------------------------------------------------------------ content.json


def fake_digest(calls):
    """A digest of the file's bytes (the layout-free digest needs real bags); counts its calls."""
    def digest(path):
        calls.append(path)
        with open(path, 'rb') as f:
            return {'sha1': hashlib.sha1(f.read()).hexdigest(), 'messages': 1, 'seconds': 0.0}
    return digest


def sha(text):
    return hashlib.sha1(text.encode()).hexdigest()


def make_bag_dir(work, name, team='TEAM', single='SINGLE', complete=True):
    d = os.path.join(str(work), 'bags', name)
    os.makedirs(d)
    for f, text in (('team.bag', team), ('team_single.bag', single)):
        with open(os.path.join(d, f), 'w') as fh:
            fh.write(text)
    if complete:
        with open(os.path.join(d, 'ok.json'), 'w') as fh:
            json.dump({'wall_s': 1.0, 'cpu_s': 1.0}, fh)
    return d


def test_bag_contents_are_digested_once_and_again_when_a_bag_changes(tmp_path):
    calls = []
    d = make_bag_dir(tmp_path, 'house-s1-aaaaaaaaaa')
    got = acc.bag_contents(d, digest=fake_digest(calls))
    assert got['team.bag']['sha1'] == sha('TEAM') and got['team_single.bag']['sha1'] == sha('SINGLE')
    assert len(calls) == 2 and os.path.exists(os.path.join(d, 'content.json'))
    assert acc.bag_contents(d, digest=fake_digest(calls)) == got
    assert len(calls) == 2                                    # kept in content.json
    with open(os.path.join(d, 'team.bag'), 'w') as fh:        # another file (its size and mtime)
        fh.write('TEAM, other')
    again = acc.bag_contents(d, digest=fake_digest(calls))
    assert len(calls) == 3 and again['team.bag']['sha1'] == sha('TEAM, other')
    assert again['team_single.bag'] == got['team_single.bag']


def test_bags_not_complete_are_not_used(tmp_path):
    calls = []
    d = make_bag_dir(tmp_path, 'house-s1-aaaaaaaaaa', complete=False)   # being made, or its make failed
    assert acc.cached_bags(d) is None
    assert acc.bag_contents(d, digest=fake_digest(calls)) is None
    assert calls == [] and not os.path.exists(os.path.join(d, 'content.json'))


def test_make_bags_dir_writes_aside_and_keeps_a_complete_dir(tmp_path):
    d = str(tmp_path / 'bags' / 'house-s1-aaaaaaaaaa')
    # a failing make: no bag directory, its own directory left for its log
    with pytest.raises(RuntimeError):
        acc.make_bags_dir(d, {'x': 1}, lambda tmp: ['/bin/sh', '-c', 'exit 3'])
    assert acc.cached_bags(d) is None and not os.path.exists(d)
    # while it runs its bags are not in d; then d is complete
    script = 'test ! -e %s && echo truth > "$0/team.truth.yaml" && echo bag > "$0/team.bag"' % d
    acc.make_bags_dir(d, {'x': 1}, lambda tmp: ['/bin/sh', '-c', script, tmp])
    assert acc.cached_bags(d) is not None
    with open(os.path.join(d, 'args.json')) as fh:
        assert json.load(fh) == {'x': 1}
    # another run making the same bags meanwhile: the complete directory is kept
    before = open(os.path.join(d, 'team.bag')).read()
    acc.make_bags_dir(d, {'x': 1}, lambda tmp: ['/bin/sh', '-c', 'echo t > "$0/team.truth.yaml"; '
                                                'echo other > "$0/team.bag"', tmp])
    assert open(os.path.join(d, 'team.bag')).read() == before
    # left: the bags and the failed make's directory (its log), nothing of the duplicate
    names = sorted(os.listdir(os.path.dirname(d)))
    assert names[0] == 'house-s1-aaaaaaaaaa' and len(names) == 2 and '.tmp-' in names[1]
    assert os.path.exists(os.path.join(os.path.dirname(d), names[1], 'make_robot_bags.log'))


# ------------------------------------------------------------------------------ migration

BINARY = ['/ws/devel/lib/gmapping/slam_gmapping_replay', 686408, 1796284261]


def run_doc(bag, robot='tb3_0'):
    return {'bag': bag, 'robot': robot, 'topic': '/%s/scan' % ('tb3_0' if robot == 'single' else robot),
            'gmapping_seed': 1, 'config': 'c0nf', 'binary': BINARY}


def old_result(work, name, robot='tb3_0', args=None, invalid=None):
    """A gmapping result of the old scheme in gmapping/NAME: its meta json and map files."""
    d = os.path.join(str(work), 'gmapping', name)
    os.makedirs(d, exist_ok=True)
    args = args or run_doc(name.rsplit('-', 1)[1], robot)
    prefix = os.path.join(d, robot)
    for ext in acc.GMAPPING_FILES:
        with open(prefix + ext, 'w') as fh:
            fh.write('%s of %s\n' % (ext, name))
    meta = {'key': acc.key_of(args), 'args': args, 'robot': robot, 'scans': 760, 'processed': 294,
            'map': '/elsewhere/%s.yaml' % robot, 'log': '/elsewhere/%s.log' % robot}
    if invalid:
        meta['invalid'] = invalid
    with open(prefix + '.json', 'w') as fh:
        json.dump(meta, fh)
    return prefix


def snapshot(root):
    out = {}
    for dp, _, fs in os.walk(str(root)):
        for f in fs:
            p = os.path.join(dp, f)
            with open(p, 'rb') as fh:
                out[p] = fh.read()
    return out


def test_an_old_result_belongs_to_its_bags_content(tmp_path):
    work = tmp_path
    old_bags = make_bag_dir(work, 'house-s1-aaaaaaaaaa')       # the old bags, their gmapping results
    old = old_result(work, 'house-s1-aaaaaaaaaa')
    old_single = old_result(work, 'house-s1-aaaaaaaaaa', 'single')
    make_bag_dir(work, 'house-s1-bbbbbbbbbb')                  # remade by new sources: the same messages
    before = snapshot(os.path.join(str(work), 'gmapping'))
    calls = []
    team, single = sha('TEAM'), sha('SINGLE')
    log = []
    prefix, meta = acc.resolve_gmapping(str(work), 'house', 1, 'tb3_0', 'team.bag', team, run_doc(team),
                                        fake_digest(calls), log.append)
    assert meta is not None and meta['cached'] and meta['migrated_now']
    assert prefix == os.path.join(acc.gmapping_dir(str(work), 'house', 1, team), 'tb3_0')
    assert os.path.basename(os.path.dirname(prefix)) == 'house-s1-content-' + team[:12]
    assert meta['key'] == acc.key_of(run_doc(team)) and meta['args'] == run_doc(team)
    assert meta['map'] == prefix + '.yaml' and meta['processed'] == 294
    assert meta['migrated_from'] == {'meta': old + '.json', 'key': acc.key_of(run_doc('aaaaaaaaaa')),
                                     'bag_key': 'aaaaaaaaaa'}
    for ext in acc.GMAPPING_FILES:                             # the same result, copied
        assert open(prefix + ext).read() == open(old + ext).read()
    with open(prefix + '.json') as fh:                         # the key rewritten in the copy
        assert json.load(fh)['key'] == acc.key_of(run_doc(team))
    assert calls == [os.path.join(old_bags, 'team.bag')]       # only the bag the old result read
    assert log and 'content.json' in log[0]
    # nothing deleted or changed in the old scheme's directory
    after = snapshot(os.path.join(str(work), 'gmapping'))
    assert all(after.get(p) == v for p, v in before.items())
    # found again by content, now in its own directory: no digest, no copy
    prefix2, meta2 = acc.resolve_gmapping(str(work), 'house', 1, 'tb3_0', 'team.bag', team, run_doc(team),
                                          fake_digest(calls))
    assert prefix2 == prefix and meta2['cached'] and not meta2.get('migrated_now') and len(calls) == 1
    # the lone robot's from team_single.bag's content
    prefix3, meta3 = acc.resolve_gmapping(str(work), 'house', 1, 'single', 'team_single.bag', single,
                                          run_doc(single, 'single'), fake_digest(calls))
    assert meta3['migrated_from']['meta'] == old_single + '.json'
    assert os.path.dirname(prefix3) == acc.gmapping_dir(str(work), 'house', 1, single)
    # a robot without an old result is to be run
    _, none = acc.resolve_gmapping(str(work), 'house', 1, 'tb3_1', 'team.bag', team, run_doc(team, 'tb3_1'),
                                   fake_digest(calls))
    assert none is None


def test_old_results_that_do_not_belong_are_not_used(tmp_path):
    work = tmp_path
    team = sha('TEAM')
    # another content
    make_bag_dir(work, 'house-s1-aaaaaaaaaa', team='TEAM, other')
    old_result(work, 'house-s1-aaaaaaaaaa')
    # its dir and its args name different bags (a copy not rewritten)
    make_bag_dir(work, 'house-s1-bbbbbbbbbb')
    old_result(work, 'house-s1-bbbbbbbbbb', args=run_doc('aaaaaaaaaa'))
    # another gmapping config
    make_bag_dir(work, 'house-s1-cccccccccc')
    old_result(work, 'house-s1-cccccccccc', args=dict(run_doc('cccccccccc'), config='other'))
    # its bags not complete (being made, or their make failed)
    make_bag_dir(work, 'house-s1-dddddddddd', complete=False)
    old_result(work, 'house-s1-dddddddddd')
    # its bags gone
    old_result(work, 'house-s1-eeeeeeeeee')
    # another seed
    make_bag_dir(work, 'house-s2-ffffffffff')
    old_result(work, 'house-s2-ffffffffff', args=dict(run_doc('ffffffffff')))
    calls = []
    assert acc.old_scheme_results(str(work), 'house', 1, 'tb3_0', 'team.bag', team, run_doc(team),
                                  fake_digest(calls)) == []
    # digested: only complete bag directories whose result is this run's but for the bag
    assert sorted(os.path.basename(os.path.dirname(p)) for p in calls) == ['house-s1-aaaaaaaaaa']
    prefix, meta = acc.resolve_gmapping(str(work), 'house', 1, 'tb3_0', 'team.bag', team, run_doc(team),
                                        fake_digest(calls))
    assert meta is None


def test_a_complete_old_result_is_preferred_and_a_stale_one_set_aside(tmp_path):
    work = tmp_path
    team = sha('TEAM')
    make_bag_dir(work, 'house-s1-aaaaaaaaaa')
    make_bag_dir(work, 'house-s1-bbbbbbbbbb')
    old_result(work, 'house-s1-aaaaaaaaaa', invalid='gmapping did not finish')
    good = old_result(work, 'house-s1-bbbbbbbbbb')
    # a result of another binary in the content's directory: set aside, not deleted
    stale = os.path.join(acc.gmapping_dir(str(work), 'house', 1, team), 'tb3_0')
    os.makedirs(os.path.dirname(stale))
    stale_args = dict(run_doc(team), binary=BINARY[:2] + [1])
    with open(stale + '.json', 'w') as fh:
        json.dump({'key': acc.key_of(stale_args), 'args': stale_args}, fh)
    prefix, meta = acc.resolve_gmapping(str(work), 'house', 1, 'tb3_0', 'team.bag', team, run_doc(team),
                                        fake_digest([]))
    assert meta['migrated_from']['meta'] == good + '.json' and not meta.get('invalid')
    aside = os.path.join(os.path.dirname(stale), 'stale-%s' % acc.key_of(stale_args), 'tb3_0.json')
    assert os.path.exists(aside)


# ------------------------------------------------------------------------------ which SLAM

RBPF_BINARY = ['/ws/devel/lib/multi_map_merge/rbpf_slam_replay', 912000, 1796290000]


def rbpf_doc(bag, robot='tb3_0'):
    return dict(run_doc(bag, robot), slam='rbpf', binary=RBPF_BINARY)


def test_the_key_names_the_slam_and_its_binary():
    team = sha('TEAM')
    gm, rb = dict(run_doc(team), slam='gmapping'), rbpf_doc(team)
    assert acc.key_of(gm) != acc.key_of(dict(gm, slam='rbpf'))         # the SLAM alone changes the key
    assert acc.key_of(rb) != acc.key_of(dict(rb, binary=BINARY))       # and so does its binary
    assert acc.slam_of(run_doc(team)) == 'gmapping'                   # written before rbpf_slam: gmapping's
    assert acc.slam_of(rb) == 'rbpf'
    # each SLAM's results in a directory of its own
    assert acc.gmapping_dir('/w', 'home', 1, team) == acc.gmapping_dir('/w', 'home', 1, team, 'gmapping')
    assert '/gmapping/' in acc.gmapping_dir('/w', 'home', 1, team, 'gmapping')
    assert '/rbpf_slam/' in acc.gmapping_dir('/w', 'home', 1, team, 'rbpf')


def test_gmapping_results_are_never_taken_for_rbpf_slams(tmp_path):
    work = tmp_path
    team = sha('TEAM')
    # gmapping results of the same bag content: of the old scheme and in the content's directory
    make_bag_dir(work, 'house-s1-aaaaaaaaaa')
    old_result(work, 'house-s1-aaaaaaaaaa')
    prefix, meta = acc.resolve_gmapping(str(work), 'house', 1, 'tb3_0', 'team.bag', team,
                                        dict(run_doc(team), slam='gmapping'), fake_digest([]))
    assert meta is not None and meta['migrated_now']                # gmapping's (no 'slam': gmapping's)
    calls = []
    before = snapshot(os.path.join(str(work), 'gmapping'))
    prefix, meta = acc.resolve_gmapping(str(work), 'house', 1, 'tb3_0', 'team.bag', team, rbpf_doc(team),
                                        fake_digest(calls))
    assert meta is None and calls == []                             # to be run; no old result looked at
    assert prefix == os.path.join(acc.gmapping_dir(str(work), 'house', 1, team, 'rbpf'), 'tb3_0')
    assert acc.old_scheme_results(str(work), 'house', 1, 'tb3_0', 'team.bag', team, rbpf_doc(team),
                                  fake_digest(calls)) == []
    assert snapshot(os.path.join(str(work), 'gmapping')) == before  # gmapping's results untouched
    # an rbpf_slam result there is found by its own key
    with open(prefix + '.json', 'w') as fh:
        json.dump({'key': acc.key_of(rbpf_doc(team)), 'args': rbpf_doc(team), 'processed': 266}, fh)
    _, meta = acc.resolve_gmapping(str(work), 'house', 1, 'tb3_0', 'team.bag', team, rbpf_doc(team),
                                   fake_digest(calls))
    assert meta['cached'] and meta['processed'] == 266
    # a gmapping-keyed result put in rbpf_slam's directory is stale, set aside, never used
    gm_doc = dict(run_doc(team), slam='gmapping')
    with open(prefix + '.json', 'w') as fh:
        json.dump({'key': acc.key_of(gm_doc), 'args': gm_doc}, fh)
    _, meta = acc.resolve_gmapping(str(work), 'house', 1, 'tb3_0', 'team.bag', team, rbpf_doc(team),
                                   fake_digest(calls))
    assert meta is None
    assert os.path.exists(os.path.join(os.path.dirname(prefix), 'stale-%s' % acc.key_of(gm_doc), 'tb3_0.json'))


def _exe(path):
    os.makedirs(os.path.dirname(path))
    with open(path, 'w') as fh:
        fh.write('#!/bin/sh\n')
    os.chmod(path, 0o755)


def test_replay_binary_per_slam(tmp_path, monkeypatch):
    ws, gm = str(tmp_path / 'ws' / 'devel'), str(tmp_path / 'gm' / 'devel')
    _exe(os.path.join(ws, 'lib', 'multi_map_merge', 'rbpf_slam_replay'))
    monkeypatch.setenv('CMAKE_PREFIX_PATH', ws + ':/usr')
    assert accuracy_slam.replay_binary('rbpf') == os.path.join(ws, 'lib', 'multi_map_merge', 'rbpf_slam_replay')
    if not os.path.exists('/opt/ros/noetic/lib/gmapping/slam_gmapping_replay'):
        assert accuracy_slam.replay_binary('gmapping') is None               # no gmapping here: INVALID and why
        why = accuracy_slam.slam_missing('gmapping')
        assert 'gmapping missing' in why and 'issue 47' in why
    _exe(os.path.join(gm, 'lib', 'gmapping', 'slam_gmapping_replay'))
    monkeypatch.setenv('CMAKE_PREFIX_PATH', gm + ':' + ws)
    assert accuracy_slam.replay_binary('gmapping') == os.path.join(gm, 'lib', 'gmapping', 'slam_gmapping_replay')
    assert 'make build' in accuracy_slam.slam_missing('rbpf')


def test_the_slam_option():
    a = accuracy.parse_args(['--quick'])
    assert a.slam == 'rbpf' and a.stem == 'accuracy_quick'
    a = accuracy.parse_args(['--slam', 'gmapping', '--worlds', 'home,intel'])
    assert a.slam == 'gmapping' and a.stem == 'accuracy_gmapping'
    with pytest.raises(SystemExit):
        accuracy.parse_args(['--slam', 'karto'])
