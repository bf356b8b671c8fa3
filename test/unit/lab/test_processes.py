"""lab/processes.py, the benchmarks' and tests' one helper for processes and ports: a process's
whole group is stopped (a child it started too), a run's CPU time and exit code, a timeout, a
stopped run refusing new processes, free ports not handed out twice."""
import os
import signal
import socket
import sys
import time

from multi_map_merge.lab import processes


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:                                  # a zombie is dead too
        with open('/proc/%d/stat' % pid) as f:
            return f.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


# a parent that starts a child ignoring SIGINT, prints the child's pid, then waits forever
PARENT = r'''
import subprocess, sys, time, signal
IGNORE = 'import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); time.sleep(600)'
c = subprocess.Popen([sys.executable, '-c', IGNORE])
print(c.pid, flush=True)
time.sleep(600)
'''


def test_stop_group_stops_the_child_too(tmp_path):
    log = str(tmp_path / 'p.log')
    p = processes.start_group([sys.executable, '-c', PARENT], log)
    end = time.time() + 20
    child = None
    while time.time() < end and child is None:
        with open(log) as f:
            text = f.read().strip()
        child = int(text) if text else None
        time.sleep(0.05)
    assert child is not None and _alive(child)
    rc = processes.stop_group(p, grace=1.0)
    assert rc is not None and rc != 0            # ended by a signal
    end = time.time() + 5
    while time.time() < end and _alive(child):
        time.sleep(0.05)
    assert not _alive(child), 'the child ignoring SIGINT outlived its group'


def test_run_timed_gives_exit_code_cpu_and_timeout(tmp_path):
    procs = processes.Processes()
    r = procs.run_timed([sys.executable, '-c', 'import sys\nx = 0\nfor i in range(3000000): x += i\nsys.exit(3)'],
                        str(tmp_path / 'a.log'), None, 60)
    assert r['rc'] == 3 and not r['timed_out']
    assert r['cpu_s'] is not None and r['cpu_s'] > 0.0
    t0 = time.time()
    r = procs.run_timed([sys.executable, '-c', 'import time; time.sleep(60)'], str(tmp_path / 'b.log'), None, 1.0)
    # stopped by SIGINT, or by SIGKILL when a loaded machine kept it from ending within the grace
    assert r['timed_out'] and r['rc'] in (-signal.SIGINT, -signal.SIGKILL) and time.time() - t0 < 30
    procs.stop_all()
    try:
        procs.start([sys.executable, '-c', 'pass'], str(tmp_path / 'c.log'))
    except RuntimeError as e:
        assert 'stopping' in str(e)
    else:
        raise AssertionError('a stopped run started a process')


def test_free_ports_are_not_handed_out_twice():
    with socket.socket() as busy:
        busy.bind(('127.0.0.1', 0))
        busy.listen(1)
        taken = busy.getsockname()[1]
        assert not processes.port_free(taken)
        a = processes.free_port(range(taken, taken + 50))
        b = processes.free_port(range(taken, taken + 50))
        assert a != taken and b != taken and a != b
        processes.release_port(a)
        assert processes.free_port(range(a, a + 1)) == a
        processes.release_port(a)
        processes.release_port(b)
