"""The address a machine announces itself by, found without name resolution: for the env loader
(``<devel>/lib/multi_map_merge/env_loader``, made by CMakeLists.txt from cmake/env_loader.in) that
roslaunch runs on a robot over ssh for ``turtlebot3_multi_slam.launch slam_on:=robot``.

roslaunch starts a remote machine's nodes as ``env ROS_MASTER_URI=<its own> <env-loader>
roslaunch -c ...`` in a non-interactive ssh session, which reads no ``~/.bashrc``: without
``ROS_IP`` or ``ROS_HOSTNAME`` the robot's roslaunch and nodes name themselves by the robot's
host name, which the base station (and the robot itself, in many images) cannot resolve
("Unable to contact my own server"). The loader sets ``ROS_IP`` to the robot's source address
on its route to the master, which the master's host reaches it back on; this needs no name to
resolve where the master URI holds an IP address (README: ``ROS_MASTER_URI=http://<base IP>:11311``).
Where the master URI holds a host name this machine cannot resolve, nothing can: the message says
so and what to change. Standard library only (a robot has no numpy or OpenCV).
"""
from __future__ import annotations

import argparse
import socket
import sys
from typing import List, Optional
from urllib.parse import urlsplit


class EnvLoaderError(ValueError):
    """Why no address could be found; the text is the whole message for the user."""


def master_host_port(master_uri: str):
    """(host, port) of a ROS_MASTER_URI such as http://192.168.0.10:11311."""
    if not master_uri:
        raise EnvLoaderError('ROS_MASTER_URI is not set: roslaunch passes its own to a remote machine; '
                             'run by hand, export ROS_MASTER_URI=http://<base station IP>:11311 first')
    try:
        parts = urlsplit(master_uri)
        host, port = parts.hostname, parts.port or 11311
    except ValueError as e:
        raise EnvLoaderError('ROS_MASTER_URI=%s is not a URI like http://192.168.0.10:11311 (%s)'
                             % (master_uri, e)) from None
    if not host:
        raise EnvLoaderError('ROS_MASTER_URI=%s names no host: expected http://<base station IP>:11311' % master_uri)
    return host, port


def master_route_address(master_uri: str) -> str:
    """This machine's IPv4 address on its route to the master of ``master_uri``: the source
    address the kernel picks for it (a UDP socket's connect sends nothing). No host name is
    resolved when the URI holds an IP address."""
    host, port = master_host_port(master_uri)
    try:
        infos = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except socket.gaierror as e:
        raise EnvLoaderError(
            'the master\'s host "%s" (ROS_MASTER_URI=%s) does not resolve on this machine (%s: %s): '
            'start roslaunch on the base station with ROS_MASTER_URI=http://<its IP address>:%d '
            '(roslaunch hands its own to the robot), or add "%s" to this machine\'s /etc/hosts'
            % (host, master_uri, socket.gethostname(), e.strerror or e, port, host)) from None
    err = None
    for _family, _type, _proto, _name, addr in infos:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.connect(addr)
                return s.getsockname()[0]
            except OSError as e:
                err = e
    raise EnvLoaderError('no route from this machine (%s) to the master %s (%s): check the network '
                         'and ROS_MASTER_URI=%s' % (socket.gethostname(), host, err, master_uri))


USAGE = """Print the IPv4 address this machine reaches the ROS master by (the master of
ROS_MASTER_URI, or of --master-uri): the address to export as ROS_IP so that every other machine
reaches this one's nodes without resolving its host name. Used by the env loader that
turtlebot3_multi_slam.launch slam_on:=robot runs on each robot
(<workspace>/devel/lib/multi_map_merge/env_loader, its default env_loader). Exit status 1, with the
reason on stderr, when there is none: no ROS_MASTER_URI, a master host name that does not resolve
here, no route to it."""


def main(argv: Optional[List[str]] = None) -> int:
    import os
    ap = argparse.ArgumentParser(prog='python3 -m multi_map_merge.ros.env_loader', description=USAGE)
    ap.add_argument('--master-uri', default=None, help='default: $ROS_MASTER_URI')
    args = ap.parse_args(argv)
    uri = os.environ.get('ROS_MASTER_URI', '') if args.master_uri is None else args.master_uri
    try:
        print(master_route_address(uri))
    except EnvLoaderError as e:
        print('env_loader: %s' % e, file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
