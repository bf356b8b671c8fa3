import os
import shutil

import pytest
from conftest import INTEL_MAP, shared_file

from multi_map_merge.cli import merge_maps as cli


@pytest.fixture
def good(tmp_path):
    yaml = shared_file(INTEL_MAP)
    for n in (yaml, yaml[:-len('yaml')] + 'pgm'):
        shutil.copy(n, tmp_path / os.path.basename(n))
    return str(tmp_path / os.path.basename(yaml))


def run(capsys, args):
    code = cli.main(args)
    return code, capsys.readouterr().err


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def test_missing_yaml(tmp_path, capsys, good):
    code, err = run(capsys, [good, str(tmp_path / 'gone.yaml'), '-o', str(tmp_path / 'o.yaml')])
    assert code == 2 and 'gone.yaml' in err


def test_yaml_without_image(tmp_path, capsys, good):
    bad = write(tmp_path, 'noimg.yaml', 'resolution: 0.05\norigin: [0, 0, 0]\n')
    code, err = run(capsys, [good, bad, '-o', str(tmp_path / 'o.yaml')])
    assert code == 2 and 'noimg.yaml' in err and 'image' in err


def test_missing_or_garbage_pgm(tmp_path, capsys, good):
    bad = write(tmp_path, 'nopgm.yaml', 'image: nothere.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n')
    code, err = run(capsys, [good, bad, '-o', str(tmp_path / 'o.yaml')])
    assert code == 2 and 'nopgm.yaml' in err and 'nothere.pgm' in err
    assert not os.path.exists(tmp_path / 'o.yaml')
    (tmp_path / 'junk.pgm').write_bytes(b'this is no image')
    bad = write(tmp_path, 'junk.yaml', 'image: junk.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n')
    code, err = run(capsys, [good, bad, '-o', str(tmp_path / 'o.yaml')])
    assert code == 2 and 'junk.yaml' in err and 'junk.pgm' in err


@pytest.mark.parametrize('res', ['0', '-1', '.nan'])
def test_bad_resolution(tmp_path, capsys, good, res):
    shutil.copy(good[:-len('yaml')] + 'pgm', tmp_path / 'r.pgm')
    bad = write(tmp_path, 'r.yaml', 'image: r.pgm\nresolution: %s\norigin: [0, 0, 0]\n' % res)
    code, err = run(capsys, [good, bad, '-o', str(tmp_path / 'o.yaml')])
    assert code == 2 and 'r.yaml' in err and 'resolution' in err


def test_nan_origin(tmp_path, capsys, good):
    shutil.copy(good[:-len('yaml')] + 'pgm', tmp_path / 'n.pgm')
    bad = write(tmp_path, 'n.yaml', 'image: n.pgm\nresolution: 0.05\norigin: [.nan, 0, 0]\n')
    code, err = run(capsys, [good, bad, '-o', str(tmp_path / 'o.yaml')])
    assert code == 2 and 'n.yaml' in err and 'origin' in err


def test_duplicate_stems_and_unknown_reference(tmp_path, capsys, good):
    os.makedirs(tmp_path / 'b')
    for n in (good, good[:-len('yaml')] + 'pgm'):
        shutil.copy(n, tmp_path / 'b' / os.path.basename(n))
    code, err = run(capsys, [good, str(tmp_path / 'b' / os.path.basename(good)), '-o', str(tmp_path / 'o.yaml')])
    assert code == 2 and 'intel' in err
    code, err = run(capsys, [good, '--reference', 'nobody', '-o', str(tmp_path / 'o.yaml')])
    assert code == 2 and 'nobody' in err
    assert not os.path.exists(tmp_path / 'o.yaml')


def test_errors_through_the_script(tmp_path):
    """The installed entry point (scripts/merge_maps) exits 2 too, message on stderr."""
    import subprocess
    import sys

    from conftest import REPO
    env = dict(os.environ, PYTHONPATH=os.path.join(REPO, 'src'))
    r = subprocess.run([sys.executable, os.path.join(REPO, 'scripts', 'merge_maps'),
                        str(tmp_path / 'gone.yaml'), '-o', str(tmp_path / 'o.yaml')],
                       capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 2 and 'gone.yaml' in r.stderr, (r.returncode, r.stderr)


@pytest.mark.parametrize('config,words', [
    ('min_agreement: 1.5\n', ['min_agreement = 1.5 is invalid', '[0, 1]']),
    ('merge_rate: 2.0\nmin_agreemnt: 0.5\n', ['unknown parameter min_agreemnt: did you mean min_agreement?']),
    ('- a list\n', ['mapping']),
])
def test_a_bad_config_is_refused_naming_the_parameter(tmp_path, capsys, good, config, words):
    cfg = write(tmp_path, 'cfg.yaml', config)
    code, err = run(capsys, [good, '--config', cfg, '-o', str(tmp_path / 'o.yaml')])
    assert code == 2 and 'cfg.yaml' in err, err
    for w in words:
        assert w in err, err
    assert not os.path.exists(tmp_path / 'o.yaml')


def test_an_alias_in_the_config_is_read_with_a_warning(tmp_path, capsys, good):
    cfg = write(tmp_path, 'cfg.yaml', 'init_pose_params: true\n')
    code, err = run(capsys, [good, '--config', cfg, '-o', str(tmp_path / 'o.yaml')])
    assert code == 0 and 'deprecated' in err and '~' not in err.split('deprecated')[0], err
