"""
A colcon workspace build installs what ``ros2 run`` and launch files need.

The current working tree (tracked files plus untracked, not ignored ones) is
copied into ``ws/src/reducer_twin`` of a temporary workspace and built once
per module with this venv's colcon. Installed programs run through
``install/setup.sh``, as a user would after sourcing it, with this venv as
the underlay (the part ``/opt/ros/jazzy`` plays on a ROS machine).
"""

import ast
import json
import os
import shutil
import signal
import subprocess
import sys

import pytest

PACKAGE = 'reducer_twin'
EXECUTABLES = (
    'reducer-twin', 'joint_simulator', 'encoder_ingest', 'te_monitor',
    'wear_estimator', 'life_publisher', 'twin_bringup',
)


def working_tree_files(repo_root):
    """
    List the files of the working tree that git does not ignore.

    Returns
    -------
    list of str
        Paths relative to ``repo_root``; tracked files deleted from the
        working tree are left out.

    """
    listing = subprocess.run(
        ['git', 'ls-files', '-z', '--cached', '--others', '--exclude-standard'],
        cwd=repo_root, check=True, capture_output=True, text=True).stdout
    return [name for name in listing.split('\0') if name and (repo_root / name).is_file()]


def run_installed(install_dir, argv, timeout):
    """
    Run a command with ``install/setup.sh`` sourced.

    The command runs in ``install_dir``: from the checkout, ``python -c``
    would import the source tree in the working directory instead.

    Parameters
    ----------
    install_dir : pathlib.Path
        The workspace's ``install`` directory.
    argv : list of str
        The command and its arguments.
    timeout : float
        Seconds before the command is killed and the test fails.

    Returns
    -------
    subprocess.CompletedProcess
        With ``stdout`` and ``stderr`` as text.

    """
    env = dict(os.environ)
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    return subprocess.run(
        ['bash', '-c', '. "$0/setup.sh" && exec "$@"', str(install_dir), *argv],
        cwd=install_dir, env=env, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope='module')
def install_dir(tmp_path_factory, repo_root, venv_bin):
    """Build the working tree with colcon once; return the ``install`` directory."""
    workspace = tmp_path_factory.mktemp('ws')
    source = workspace / 'src' / PACKAGE
    for name in working_tree_files(repo_root):
        (source / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(repo_root / name, source / name)
    build = subprocess.run(
        [str(venv_bin / 'colcon'), 'build', '--event-handlers', 'console_direct+'],
        cwd=workspace, capture_output=True, text=True, timeout=600)
    if build.returncode != 0:
        pytest.fail(
            f'colcon build failed (exit {build.returncode}):\n'
            f'{build.stdout[-4000:]}\n{build.stderr[-4000:]}')
    return workspace / 'install'


def test_every_executable_is_installed_where_ros2_run_looks(install_dir):
    lib = install_dir / PACKAGE / 'lib' / PACKAGE
    missing = [name for name in EXECUTABLES if not os.access(lib / name, os.X_OK)]
    assert missing == [], f'not executable or missing in {lib}: {missing}'


def test_package_xml_index_marker_and_every_config_file_are_installed(install_dir, repo_root):
    share = install_dir / PACKAGE / 'share' / PACKAGE
    assert (share / 'package.xml').is_file()
    index = install_dir / PACKAGE / 'share' / 'ament_index' / 'resource_index' / 'packages'
    assert (index / PACKAGE).is_file(), 'ament index marker not installed'
    source_configs = sorted(path.name for path in (repo_root / 'config').glob('*.yaml'))
    installed_configs = sorted(path.name for path in (share / 'config').glob('*.yaml'))
    assert source_configs, 'config/ holds no *.yaml parameter file to install'
    assert installed_configs == source_configs


def test_installed_programs_import_the_installed_package(install_dir):
    result = run_installed(
        install_dir, [sys.executable, '-c', f'import {PACKAGE}; print({PACKAGE}.__file__)'],
        timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().startswith(str(install_dir / PACKAGE)), result.stdout


def test_installed_cli_prints_the_paper_tables_as_json(install_dir):
    exe = install_dir / PACKAGE / 'lib' / PACKAGE / 'reducer-twin'
    result = run_installed(install_dir, [str(exe), 'paper', '--json'], timeout=120)
    assert result.returncode == 0, f'reducer-twin paper --json failed:\n{result.stderr}'
    assert 'table2' in json.loads(result.stdout)


def test_installed_joint_simulator_runs_on_the_installed_params_file_until_ctrl_c(install_dir):
    # What `ros2 run reducer_twin joint_simulator --ros-args --params-file ...` does.
    exe = install_dir / PACKAGE / 'lib' / PACKAGE / 'joint_simulator'
    params = install_dir / PACKAGE / 'share' / PACKAGE / 'config' / 'nodes.yaml'
    env = dict(os.environ)
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    # exec: the signal goes to the node program itself, as from a terminal's Ctrl-C.
    proc = subprocess.Popen(
        ['bash', '-c', '. "$0/setup.sh" && exec "$@"', str(install_dir), str(exe),
         '--ros-args', '--params-file', str(params)],
        cwd=install_dir, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        try:
            proc.wait(timeout=3.0)
        except subprocess.TimeoutExpired:
            pass
        alive = proc.poll() is None
        if alive:
            proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert alive, f'joint_simulator exited within 3 s (exit {proc.returncode}):\n{err}'
    assert proc.returncode == 0, f'exit {proc.returncode} after SIGINT:\n{err}'
    assert 'Traceback' not in err, err
    assert "simulating 1 joint(s) ['joint_1'] at 1000 Hz" in out + err


def test_the_launch_file_is_installed_and_names_an_installed_executable_and_its_parameter(
        install_dir, repo_root):
    # launch_ros is not on PyPI: the file is read as Python source, not run.
    share = install_dir / PACKAGE / 'share' / PACKAGE
    launch = share / 'launch' / 'twin.launch.py'
    assert launch.is_file(), 'launch/twin.launch.py not installed to share/reducer_twin/launch'
    tree = ast.parse(launch.read_text())
    calls = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            calls.setdefault(node.func.id, []).append(node)
    [node_call] = calls['Node']
    kwargs = {k.arg: k.value for k in node_call.keywords}
    assert ast.literal_eval(kwargs['package']) == PACKAGE
    executable = ast.literal_eval(kwargs['executable'])
    assert os.access(install_dir / PACKAGE / 'lib' / PACKAGE / executable, os.X_OK)
    [params] = kwargs['parameters'].elts
    names = [ast.literal_eval(key) for key in params.keys]
    bringup = (repo_root / 'reducer_twin' / 'nodes' / f'{executable}.py').read_text()
    for name in names:
        assert f"declare_parameter('{name}'" in bringup, f'{executable} declares no {name!r}'
    default = calls['PathJoinSubstitution'][0].args[0].elts
    assert [ast.literal_eval(e) for e in default[1:]] == ['config', 'twin.yaml']
    assert (share / 'config' / 'twin.yaml').is_file()
