"""The README's own commands, run as a user runs them: `rosrun multi_map_merge ...` and
`roslaunch multi_map_merge ...` in the workspace `make` built (no master needed).

On a machine missing a package (rosbash has `rosrun`) these fail, as they would for the user."""
import glob
import json
import os
import re
import shutil
import subprocess

import pytest
import yaml
from conftest import MAZE, REPO, shared_file

README = os.path.join(REPO, 'README.md')
# the README's pages in docs/ (real robots, bag replay, offline tools, ...): their commands too
DOCS = sorted(glob.glob(os.path.join(REPO, 'docs', '*.md')))


def _readme_commands(tool, pages=(README,) + tuple(DOCS)):
    """Every distinct `<tool> multi_map_merge NAME` the README (and its docs pages) show."""
    text = ''
    for page in pages:
        with open(page) as f:
            text += f.read()
    return sorted(set(re.findall(r'\b%s multi_map_merge ([A-Za-z0-9_.]+)' % tool, text)))


def _run(cmd, cwd=None, timeout=120):
    if shutil.which(cmd[0]) is None:
        pytest.fail('`%s` is not on PATH: the package providing it is not installed (the Makefile '
                    'installs rosbash for rosrun, python3-roslaunch for roslaunch)' % cmd[0])
    return subprocess.run(cmd, cwd=cwd, timeout=timeout, capture_output=True, text=True)


@pytest.fixture(autouse=True)
def _workspace():
    if 'ROS_PACKAGE_PATH' not in os.environ:
        pytest.skip('no catkin workspace sourced: run through `make test` (or source the workspace)')


def test_readme_shows_the_offline_tools():
    assert {'merge_maps', 'evaluate_map'} <= set(_readme_commands('rosrun', pages=(README,)))


@pytest.mark.parametrize('name', _readme_commands('rosrun'))
def test_every_rosrun_command_of_the_readme_starts(name):
    r = _run(['rosrun', 'multi_map_merge', name, '--help'])
    assert r.returncode == 0, r.stdout + r.stderr
    assert 'usage' in r.stdout.lower()


@pytest.mark.parametrize('name', _readme_commands('roslaunch'))
def test_every_roslaunch_file_of_the_readme_loads(name):
    r = _run(['roslaunch', '--ros-args', 'multi_map_merge', name])
    assert r.returncode == 0, r.stdout + r.stderr


def test_readme_merge_then_evaluate(tmp_path):
    """`rosrun multi_map_merge merge_maps` on three real Turtlebot3 gmapping maps, then
    `rosrun multi_map_merge evaluate_map` of the result against the maze's full map."""
    maze = shared_file(MAZE)
    for name in os.listdir(maze):
        shutil.copy(os.path.join(maze, name), tmp_path / name)
    maps = ['tb3_0_map.yaml', 'tb3_1_map.yaml', 'tb3_2_map.yaml']
    r = _run(['rosrun', 'multi_map_merge', 'merge_maps'] + maps
             + ['-o', 'merged.yaml', '--transforms', 'T.yaml'], cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    with open(tmp_path / 'T.yaml') as f:
        report = yaml.safe_load(f)
    assert all(m['merged'] for m in report['maps'].values()), report
    r = _run(['rosrun', 'multi_map_merge', 'evaluate_map', 'merged.yaml', 'dans_maze_map.yaml',
              '--json', 'eval.json'], cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    with open(tmp_path / 'eval.json') as f:
        scores = json.load(f)
    assert scores['fitness'] >= 0.9, scores
