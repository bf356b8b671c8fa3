"""rbpf_slam's gyro scale estimator (src/rbpf_slam/gyro_scale.cpp, no MRPT, no ROS) on synthetic
steps of known truth: a Burger spinning on the spot in 0.3 rad steps (the LDS-02's 5 Hz scans at
1.5 rad/s), its gyro reporting the true turn times a fixed scale, each step's scan-match turn the
true turn plus the match's noise. Built here with g++ (test/unit/rbpf/gyro_scale_check.cpp drives
it); skips where g++ is absent."""
import math
import os
import shutil
import subprocess

import numpy as np
import pytest

REPO = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', '..'))
SOURCES = [os.path.join(REPO, 'test', 'unit', 'rbpf', 'gyro_scale_check.cpp'),
           os.path.join(REPO, 'src', 'rbpf_slam', 'gyro_scale.cpp')]


@pytest.fixture(scope='module')
def check_binary(tmp_path_factory):
    """The estimator's driver, compiled from the package's own source."""
    gxx = shutil.which('g++')
    if gxx is None:
        pytest.skip('g++ is absent: the estimator (C++) cannot be built here')
    exe = str(tmp_path_factory.mktemp('gyro') / 'gyro_scale_check')
    subprocess.run([gxx, '-std=c++17', '-O1', '-I', os.path.join(REPO, 'src', 'rbpf_slam'), '-o', exe] + SOURCES,
                   check=True)
    return exe


def run(exe, steps, enabled=True, limit=0.05, window=math.pi / 2, prior_sigma=0.01):
    """The factor applied after each step, and (applied, estimate, used, rejected, updates) at the end."""
    text = ''.join('%.12f %.12f\n' % (x, y) for x, y in steps)
    out = subprocess.run([exe, '1' if enabled else '0', str(limit), str(window), str(prior_sigma)],
                         input=text, capture_output=True, text=True, check=True).stdout.split('\n')
    applied = [float(v) for v in out[:-2]]
    final = out[-2].split()
    assert final[0] == 'final'
    return applied, (float(final[1]), float(final[2]), int(final[3]), int(final[4]), int(final[5]))


def spin_steps(gyro_scale, n, rng, noise=0.01, step=0.3):
    """n steps of a spin (alternating direction every 20 steps, as a Burger turns toward each place):
    (gyro's turn, scan match's turn), rad."""
    true = step * (1 + 0.1 * rng.standard_normal(n)) * np.where((np.arange(n) // 20) % 2 == 0, 1.0, -1.0)
    return list(zip(gyro_scale * true, true + noise * rng.standard_normal(n)))


def test_learns_a_gyros_scale_from_its_spins(check_binary):
    rng = np.random.default_rng(7)
    gyro_scale = 1 - 0.0175      # tb3_0 of tb3_real_launch's bag: its gyro reads 1.75 % short
    steps = spin_steps(gyro_scale, 400, rng)
    applied, (last, estimate, used, rejected, updates) = run(check_binary, steps)
    assert estimate == pytest.approx(1 / gyro_scale, abs=0.002)
    assert last == pytest.approx(estimate, abs=0.002)
    assert used == 400 and rejected == 0
    # the factor applied moves once per 90 degrees of odometry turn, not on every step
    turned = np.cumsum([abs(x) for x, _ in steps])
    first = int(np.argmax(turned >= math.pi / 2))
    assert all(a == 1.0 for a in applied[:first]) and applied[first] != 1.0
    assert updates == int(turned[-1] // (math.pi / 2))


def test_poor_matches_are_left_out(check_binary):
    rng = np.random.default_rng(8)
    gyro_scale = 1 + 0.02
    steps = spin_steps(gyro_scale, 400, rng)
    wrong = rng.choice(400, 20, replace=False)   # a wall mistaken for another: 10 degrees off
    steps = [(x, y + (0.17 if i in wrong else 0.0)) for i, (x, y) in enumerate(steps)]
    _, (_, estimate, used, rejected, _) = run(check_binary, steps)
    assert rejected == 20 and used == 380
    assert estimate == pytest.approx(1 / gyro_scale, abs=0.002)


def test_bounded_and_off(check_binary):
    rng = np.random.default_rng(9)
    # a match that always turns 10 % more than the gyro: the factor stops at the 5 % limit
    steps = [(x, 1.1 * x) for x, _ in spin_steps(1.0, 200, rng, noise=0.0)]
    _, (last, estimate, _, _, _) = run(check_binary, steps, limit=0.05)
    assert estimate == pytest.approx(1.05) and last == pytest.approx(1.05)
    # off: the odometry's turns as they are
    applied, (last, _, used, _, _) = run(check_binary, spin_steps(0.97, 200, rng), enabled=False)
    assert last == 1.0 and set(applied) == {1.0} and used == 0


def test_no_turns_keep_the_prior(check_binary):
    rng = np.random.default_rng(10)
    # driving straight: tiny turns, the match's noise much larger than them, so nothing is learned
    steps = [(x, x + 0.01 * rng.standard_normal()) for x in 0.002 * rng.standard_normal(300)]
    _, (last, estimate, _, _, updates) = run(check_binary, steps)
    assert updates == 0 and last == 1.0
    assert estimate == pytest.approx(1.0, abs=0.002)
