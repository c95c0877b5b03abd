"""
Fleets on Ray: ``reducer-twin analyze ... --engine ray [--ray-address ADDR] --jobs N``.

Every bag is a Ray task; a bag's task takes the chain state its robot's previous bag
returned (a Ray object), so the bags of one robot follow one another while robots run
in parallel, on any node. The tasks run the same
:func:`~reducer_twin.fleet.history.analyse_in_chain` as the local engine, in one
process each (no forked helpers inside a Ray worker), so the results are the local
ones to the last digit; only this process (the driver) writes the store.

Without ``--ray-address`` a Ray of ``--jobs`` CPUs is started for the run and stopped
after it, in a temporary directory of its own, without dashboard or usage reporting,
and on the loopback interface only: Ray resolves ``127.0.0.1`` to the machine's
routable address on purpose (its nodes must reach each other), which a one-machine run
started on demand does not need, so that resolution is bypassed while it starts. With
``--ray-address`` the run joins an existing cluster, whose nodes must have
reducer_twin installed and see the bags and the output directory at the same paths.
"""

import contextlib
import os
from pathlib import Path
import shutil
import signal
import tempfile
import threading

from reducer_twin.analysis.forking import STOP_WAIT_S
from reducer_twin.core.errors import BagError, InvalidParameter


def _ray():
    os.environ.setdefault('RAY_USAGE_STATS_ENABLED', '0')
    try:
        import ray
    except ImportError:
        raise InvalidParameter('--engine ray needs Ray, which is not installed: pip install '
                               "'reducer_twin[fleet]' (or pip install ray)") from None
    return ray


@contextlib.contextmanager
def _keeping_sigterm():
    """
    Keep this command's SIGTERM handler across ``ray.init``, which replaces it.

    Ray's handler exited 1 without a word or a clean-up; the command's own stops the
    run as Ctrl-C does (the bags' tasks cancelled, nothing incomplete left).
    """
    handler = signal.getsignal(signal.SIGTERM)
    try:
        yield
    finally:
        if handler is not None and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, handler)


def start_local(jobs):
    """
    Start a Ray of ``jobs`` CPUs on this machine, listening on 127.0.0.1 only.

    Parameters
    ----------
    jobs : int
        CPUs the cluster offers (tasks at once).

    Returns
    -------
    str
        Its temporary directory (removed by :func:`stop`).

    """
    ray = _ray()
    from ray._private import services
    # Workers import this package as the driver does.
    package_root = str(Path(__file__).resolve().parents[2])
    path = os.environ.get('PYTHONPATH', '')
    if package_root not in path.split(os.pathsep):
        os.environ['PYTHONPATH'] = os.pathsep.join(p for p in (package_root, path) if p)
    temp_dir = tempfile.mkdtemp(prefix='rt-ray-', dir='/tmp')
    saved = services.resolve_ip_for_localhost, services.get_node_ip_address
    services.resolve_ip_for_localhost = lambda host: host
    services.get_node_ip_address = lambda address=None: '127.0.0.1'
    try:
        with _keeping_sigterm():
            ray.init(address='local', num_cpus=int(jobs), include_dashboard=False,
                     _node_ip_address='127.0.0.1', _temp_dir=temp_dir,
                     log_to_driver=False, configure_logging=False)
    except BaseException:
        shutil.rmtree(temp_dir, ignore_errors=True)
        raise
    finally:
        services.resolve_ip_for_localhost, services.get_node_ip_address = saved
    return temp_dir


def connect(address):
    """Join an existing Ray cluster at ``address``."""
    ray = _ray()
    try:
        with _keeping_sigterm():
            ray.init(address=address, log_to_driver=False, configure_logging=False)
    except (ConnectionError, ValueError, RuntimeError) as err:
        raise InvalidParameter(f'--ray-address {address}: cannot join the Ray cluster: '
                               f'{err}') from None


def stop(temp_dir=None):
    """Leave (or stop the on-demand) Ray and remove its temporary directory."""
    ray = _ray()
    ray.shutdown()
    if temp_dir:
        shutil.rmtree(temp_dir, ignore_errors=True)


def _task(item, chain, settings, overwrite):
    """Body of a bag's Ray task: analyse it, continuing its robot's chain."""
    import ray
    from reducer_twin.fleet.history import analyse_in_chain
    node = ray.get_runtime_context().get_node_id()
    return analyse_in_chain(item, chain, settings, overwrite, node=node)


def run_ray(chains, start, settings, overwrite, jobs, address=None):
    """
    Run the chains as Ray tasks and yield each bag's outcome as it ends.

    Parameters
    ----------
    chains : dict of str to list of ChainItem
        Per robot, the bags in order.
    start : dict of str to dict
        Per robot, the stored state of each joint's reducer.
    settings : AnalysisSettings
        How to analyse.
    overwrite : bool
        Replace derived bags already there.
    jobs : int
        CPUs of an on-demand Ray.
    address : str, optional
        An existing cluster to join instead.

    Yields
    ------
    Done
        Per bag, in chain order within each robot.

    """
    ray = _ray()
    temp_dir = None
    if address:
        connect(address)
    else:
        temp_dir = start_local(jobs)
    pending = {}
    try:
        task = ray.remote(num_cpus=1, num_returns=2, max_retries=0)(_task)
        settings_ref = ray.put(settings)
        for robot, items in chains.items():
            chain = {'ok': True, 'why': '', 'states': dict(start.get(robot, {}))}
            refs = []
            for item in items:
                done_ref, chain = task.remote(item, chain, settings_ref, overwrite)
                refs.append((item, done_ref))
            pending[robot] = refs
        yield from _collect(ray, pending)
    except BaseException:   # a stop, an error, or the loop left (GeneratorExit)
        _cancel(ray, [ref for refs in pending.values() for _, ref in refs])
        raise
    finally:
        stop(temp_dir)


def _cancel(ray, refs):
    """
    Cancel the bags' tasks still queued or running, and wait for them to end.

    A running task gets ``KeyboardInterrupt``, so that its bag removes what it was
    writing, as a stopped command does; stopped at once with the cluster, tasks left
    their partial derived bags and locks beside the outputs.
    """
    for ref in refs:
        try:
            ray.cancel(ref)
        except Exception:  # noqa: B902 - a task already ended: nothing to cancel
            pass
    if refs:
        ray.wait(refs, num_returns=len(refs), timeout=STOP_WAIT_S)


def _collect(ray, pending):
    """Yield the outcomes in chain order as their tasks end."""
    from reducer_twin.fleet.history import Done
    waiting = {ref: robot for robot, refs in pending.items() for _, ref in refs}
    finished = set()
    while waiting:
        ready, _ = ray.wait(list(waiting), num_returns=1)
        for ref in ready:
            finished.add(ref)
            del waiting[ref]
        for robot, refs in pending.items():
            while refs and refs[0][1] in finished:
                item, ref = refs.pop(0)
                try:
                    yield ray.get(ref)
                except ray.exceptions.RayError as err:
                    yield Done(item, BagError(f'{item.info.path}: the Ray task failed: {err}'))
