"""The node's Python log lines (the core's and the runtime's, e.g. a Dask cluster left for the
local workers) reach rospy's log functions, hence /rosout and the screen: rospy's logging
configuration would give them only the node's log file. No master here."""
import logging

import pytest

pytest.importorskip('rospy')   # the ROS shell: not on a stack without ROS (make test-focal)
pytest.importorskip('diagnostic_updater')

from multi_map_merge.ros import node  # noqa: E402


def test_the_package_warnings_go_to_rospy_once(monkeypatch):
    seen = []
    for level in ('logwarn', 'logerr', 'loginfo'):
        monkeypatch.setattr(node.rospy, level, lambda fmt, *a, level=level: seen.append((level, fmt % a)))
    logger = logging.getLogger('multi_map_merge')
    before = list(logger.handlers), logger.propagate
    try:
        node.log_to_rosout()
        node.log_to_rosout()    # (once: not a second handler)
        logging.getLogger('multi_map_merge.runtime.cluster').warning('multi_map_merge: %s', 'cluster lost')
        logging.getLogger('multi_map_merge.core').info('not shown')
        assert seen == [('logwarn', 'multi_map_merge: cluster lost')]
    finally:
        logger.handlers[:], logger.propagate = before
