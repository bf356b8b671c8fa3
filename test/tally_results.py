#!/usr/bin/env python3
"""The last line of ``make test``: unit tests and rostests counted as passed, failed and skipped.

Reads a directory holding ``unit.xml`` (pytest's ``--junitxml``; ``ros2.xml`` too, the ROS 2
node's tests, where they ran) and one ``NAME.log`` per rostest
(``rostest --text``'s whole output, its test nodes' unittest output included). A rostest counts
as failed unless its summary says ``RESULT: SUCCESS``; as skipped when it succeeded and every
one of its test cases skipped (rosunit's summary counts a skipped case as a success, so the
skips are read from the test nodes' own unittest lines, ``OK (skipped=N)``); else as passed.
Prints the line and exits 1 when anything failed or a result is missing, else 0.

Usage: tally_results.py DIR"""
import os
import re
import sys
import xml.etree.ElementTree as ET

ANSI = re.compile(r'\x1b\[[0-9;]*m')


def unit_counts(path):
    """(passed, failed, skipped) of pytest's JUnit XML at ``path``; None when it is missing or
    unreadable (pytest did not get to write it)."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return None
    suites = [root] if root.tag == 'testsuite' else root.findall('testsuite')
    total = failed = skipped = 0
    for s in suites:
        total += int(s.get('tests', 0))
        failed += int(s.get('failures', 0)) + int(s.get('errors', 0))
        skipped += int(s.get('skipped', 0))
    return total - failed - skipped, failed, skipped


def rostest_outcome(text):
    """'passed', 'failed' or 'skipped' of one rostest's ``--text`` output."""
    text = ANSI.sub('', text)
    if not re.search(r'RESULT: SUCCESS', text):
        return 'failed'
    tests = sum(int(n) for n in re.findall(r'^\s*\* TESTS: (\d+)', text, re.M))
    skipped = sum(int(n) for n in re.findall(r'\bskipped=(\d+)\)', text))
    return 'skipped' if skipped and skipped >= tests else 'passed'


def main(argv):
    if len(argv) != 2:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    d = argv[1]
    unit = unit_counts(os.path.join(d, 'unit.xml'))
    rostests = {'passed': [], 'failed': [], 'skipped': []}
    for name in sorted(os.listdir(d)):
        if name.endswith('.log'):
            with open(os.path.join(d, name), errors='replace') as f:
                rostests[rostest_outcome(f.read())].append(name[:-len('.log')])
    unit_text = 'unit %d passed, %d failed, %d skipped' % unit if unit else 'unit: no results (pytest wrote none)'
    for what in ('failed', 'skipped'):
        if rostests[what]:
            print('rostests %s: %s' % (what, ' '.join(rostests[what])))
    # the ROS 2 node's tests, where make test ran them (ros2.xml)
    ros2 = unit_counts(os.path.join(d, 'ros2.xml')) if os.path.exists(os.path.join(d, 'ros2.xml')) else None
    ros2_text = '' if ros2 is None else '; ros2 %d passed, %d failed, %d skipped' % ros2
    print('make test: %s; rostests %d passed, %d failed, %d skipped%s'
          % (unit_text, len(rostests['passed']), len(rostests['failed']), len(rostests['skipped']), ros2_text))
    return 1 if unit is None or unit[1] or rostests['failed'] or (ros2 is not None and ros2[1]) else 0


if __name__ == '__main__':
    sys.exit(main(sys.argv))
