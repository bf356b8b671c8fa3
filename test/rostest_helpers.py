"""Helpers shared by the rostest scripts in this directory (not a test itself)."""
import os
import signal
import subprocess

import rospkg


def shared_data() -> str:
    """``../shared/data`` beside the package (``MMM_SHARED_DATA`` overrides it; point it at a
    missing directory to see the tests skip)."""
    env = os.environ.get('MMM_SHARED_DATA')
    if env is not None:
        return env
    pkg = os.path.realpath(rospkg.RosPack().get_path('multi_map_merge'))
    return os.path.join(os.path.dirname(pkg), 'shared', 'data')


def stop_launch(proc: subprocess.Popen, timeout: float = 20.0) -> None:
    """Stop a roslaunch started with ``start_new_session=True``: SIGINT to its process group
    (roslaunch then stops its nodes), SIGKILL if it has not ended within ``timeout``."""
    os.killpg(proc.pid, signal.SIGINT)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
