"""
What the live benchmarks share: DDS kept on this machine, the bringup they run, process figures.

``bench_live_chain.py`` and ``bench_soak.py`` run the same thing, the
6-joint bringup with the simulator in one process as ``twin_bringup`` builds
it, and read the same figures of this process.
"""

import os
import tempfile

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('FASTDDS_BUILTIN_TRANSPORTS', 'SHM')
os.environ.setdefault('ROS_DOMAIN_ID', str(40 + os.getpid() % 50))


def start_bringup(joints, state_prefix):
    """
    Start rclpy and the bringup with the simulator; return ``(nodes, executor, state_dir)``.

    Parameters
    ----------
    joints : int
        Number of simulated joints (1 kHz each).
    state_prefix : str
        Prefix of the temporary directory of the estimator state files.

    Returns
    -------
    tuple
        ``nodes`` as :func:`reducer_twin.nodes.twin_bringup.build_nodes` returns
        them, the executor spinning them all, and the state directory.

    """
    import rclpy
    from reducer_twin.nodes.runtime import make_executor, quiet_gc
    from reducer_twin.nodes.twin_bringup import all_nodes, build_nodes, load_config
    state_dir = tempfile.mkdtemp(prefix=state_prefix)
    config = load_config(None)
    config['twin'].update({'joints': [f'joint_{k + 1}' for k in range(joints)],
                           'aging_factor': 36000.0, 'simulate': True, 'state_dir': state_dir})
    rclpy.init(args=['--ros-args', '--log-level', 'warn'])
    nodes = build_nodes(config)
    executor = make_executor()
    for node in all_nodes(nodes):
        executor.add_node(node)
    quiet_gc()
    return nodes, executor, state_dir


def rss_mb():
    """Return the resident set size of this process [MB]."""
    with open('/proc/self/statm') as fh:
        return int(fh.read().split()[1]) * os.sysconf('SC_PAGE_SIZE') / 1e6


def rss_kinds_mb():
    """
    Return the resident memory of this process by kind [MB].

    Returns
    -------
    dict
        ``anonymous`` (heaps, interpreter arenas, stacks), ``file`` (pages
        of mapped files: the shared libraries' code and data as it is first
        used) and ``shared`` (shared memory: Fast DDS's transport segments),
        from ``/proc/self/status``; empty where the kernel does not say.

    """
    keys = {'RssAnon:': 'anonymous', 'RssFile:': 'file', 'RssShmem:': 'shared'}
    out = {}
    with open('/proc/self/status') as fh:
        for line in fh:
            parts = line.split()
            if parts and parts[0] in keys:
                out[keys[parts[0]]] = int(parts[1]) * 1024 / 1e6
    return out


def steal_s():
    """Return the CPU time the hypervisor has given other guests so far [s], or None."""
    try:
        with open('/proc/stat') as fh:
            return int(fh.readline().split()[8]) / os.sysconf('SC_CLK_TCK')
    except (OSError, ValueError, IndexError):
        return None
