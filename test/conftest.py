"""
Set-up shared by every test of the package.

The ROS network variables are set when this file is imported, before any test
module can import rclpy, and every subprocess a test starts inherits them:

- ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and
  ``FASTDDS_BUILTIN_TRANSPORTS=SHM``: no DDS packet leaves the machine
  (ros2-notes, "Network hygiene").
- ``ROS_DOMAIN_ID``: always chosen here, whatever the caller's environment
  says, so that two test suites running at once on one machine (two checkouts,
  CI beside a developer, an acceptance check beside ``make test``) never see
  each other's topics. The id, in 1..100, starts from the process id and is
  held with a lock file in the temporary directory for the whole session; an
  id another live suite holds is skipped.
- ``MPLBACKEND=Agg``: plots render without a display.
- ``XDG_STATE_HOME``: a new temporary directory, where nodes started without a state file
  keep their state.

The directory of the running interpreter (the venv's ``bin``) is put first on
``PATH`` so that subprocesses find this venv's ``colcon``, ``reducer-twin`` and
node executables and never mix venvs in one process tree.
"""

import atexit
import fcntl
import os
from pathlib import Path
import shutil
import sys
import tempfile

from hypothesis import settings
import pytest

DOMAIN_IDS = range(1, 101)

# Everything the package ships or runs that the lint tests check; .venv, build,
# install and log are never linted because they are not listed.
LINTED = ('reducer_twin', 'msg_adapters', 'test', 'bench', 'setup.py')

_domain_lock_fd = None


def _reserve_domain_id():
    """
    Pick a ROS domain id no other test session on this machine holds.

    Returns
    -------
    int
        The domain id, locked for the lifetime of this process; when all ids
        are taken, the one derived from the process id, unlocked.

    """
    global _domain_lock_fd
    first = os.getpid() % len(DOMAIN_IDS)
    for offset in range(len(DOMAIN_IDS)):
        domain_id = DOMAIN_IDS[(first + offset) % len(DOMAIN_IDS)]
        lock_path = os.path.join(
            tempfile.gettempdir(), f'reducer_twin_test_ros_domain_{domain_id}.lock')
        try:
            fd = os.open(lock_path, os.O_CREAT | os.O_RDWR, 0o666)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        _domain_lock_fd = fd
        return domain_id
    return DOMAIN_IDS[first]


os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ['FASTDDS_BUILTIN_TRANSPORTS'] = 'SHM'
os.environ['MPLBACKEND'] = 'Agg'
# The nodes' default state files (<joint>.json, <joint>.te_monitor.json) go to a directory of
# this session: a test never continues from an earlier run's state, nor writes the user's.
os.environ['XDG_STATE_HOME'] = tempfile.mkdtemp(prefix='reducer_twin_test_state_')
atexit.register(shutil.rmtree, os.environ['XDG_STATE_HOME'], True)
os.environ['ROS_DOMAIN_ID'] = str(_reserve_domain_id())
os.environ['PATH'] = os.pathsep.join(
    [os.path.dirname(sys.executable), os.environ.get('PATH', '')])

# Hypothesis' 200 ms deadline can fail at random on a loaded 2-core machine; CI
# runs use Hypothesis' own 'ci' profile, which this keeps (and which already has
# no deadline).
settings.register_profile('reducer_twin', settings.default, deadline=None)
settings.load_profile('reducer_twin')


def pytest_configure(config):
    """Keep the core's transmission-error tables on disk, as the command and the nodes do."""
    from reducer_twin.io import table_cache
    table_cache.install()


def pytest_report_header(config):
    """Show the ROS network set-up at the top of the test report."""
    names = ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'FASTDDS_BUILTIN_TRANSPORTS')
    return 'ros: ' + ', '.join(f'{name}={os.environ[name]}' for name in names)


@pytest.fixture(scope='session')
def repo_root():
    """Return the root of the checkout (the directory holding package.xml)."""
    return Path(__file__).resolve().parent.parent


@pytest.fixture(scope='session')
def shared_dir(repo_root):
    """
    Return the shared material beside the checkout (``../shared``).

    Fails the test, rather than skipping it, when the directory is missing:
    CI and the acceptance checks always provide it.
    """
    path = repo_root.parent / 'shared'
    if not path.is_dir():
        pytest.fail(f'shared directory expected beside the checkout at {path}, not found')
    return path


@pytest.fixture(scope='session')
def rosbag2_jazzy_dir(shared_dir):
    """Return the bags rosbag2 wrote on Jazzy (``../shared/data/rosbag2-jazzy``)."""
    path = shared_dir / 'data' / 'rosbag2-jazzy'
    if not path.is_dir():
        pytest.fail(f'rosbag2 Jazzy bags expected at {path}, not found')
    return path


@pytest.fixture(scope='session')
def venv_bin():
    """
    Return the ``bin`` directory of the interpreter running the tests.

    ``sys.executable`` is not resolved: in a venv it is a symlink whose
    directory is the venv's ``bin``, next to ``colcon`` and the console scripts.
    """
    return Path(sys.executable).parent


@pytest.fixture(scope='session')
def lint_paths(repo_root):
    """Return the absolute paths the lint tests check (those that exist)."""
    return [str(repo_root / name) for name in LINTED if (repo_root / name).exists()]
