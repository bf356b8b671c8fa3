"""What the node's process reads before ``rospy.init_node``: ``~workers``, so that the worker
pool is forked before rospy starts its threads."""
from __future__ import annotations

import sys

from .params import resolve_params

NODE_NAME = 'map_merge'


def workers_before_init(argv=None) -> int:
    """``~workers`` as the node will read it, read before ``rospy.init_node`` (which starts
    threads): from a ``_workers:=N`` argument, else from the parameter server (XML-RPC calls, no
    thread; the node's name and namespace from ``__name:=``, ``__ns:=`` or ROS_NAMESPACE, as rospy
    resolves them). 0 (one per core) when it is not set, cannot be read within 2 s or is invalid
    (load_params says why later). The pool must be forked now: a pool of another size started
    once threads run comes from a forkserver, which imports OpenCV again (about 100 MB more for
    the node's tree on the house maps)."""
    import socket

    import rosgraph
    import rosgraph.names
    import yaml
    argv = sys.argv if argv is None else argv
    value = None
    for a in argv:
        if a.startswith('_workers:='):
            try:
                value = yaml.safe_load(a.split(':=', 1)[1])
            except yaml.YAMLError:
                value = a.split(':=', 1)[1]
    if value is None:
        mappings = rosgraph.names.load_mappings(argv)
        name = rosgraph.names.ns_join(rosgraph.names.get_ros_namespace(argv=argv),
                                      mappings.get('__name', NODE_NAME))
        old = socket.getdefaulttimeout()
        socket.setdefaulttimeout(2.0)
        try:
            value = rosgraph.Master(name).getParam(rosgraph.names.ns_join(name, 'workers'))
        except Exception:   # not set (MasterError), no master yet (rosrun before roscore), unreachable
            return 0
        finally:
            socket.setdefaulttimeout(old)
    return resolve_params({'workers': value}).config.workers
