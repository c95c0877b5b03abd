"""Fleets on Ray: a real local cluster gives the local engine's results to the last digit."""

import json
import os
from pathlib import Path
import signal

from cli_runs import run_cli as _run, several_bags_stopped, STOP_IDS, STOPS
import pytest
import ray  # noqa: F401 - the 'fleet' extra the Makefile installs; missing Ray fails here
from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec
import yaml

LIFE = {'hours': 1500.0, 'aging_factor': 360_000.0, 'joints': 2, 'rate_hz': 250.0}


def _listening_sockets(pids):
    """Local addresses of the TCP sockets these processes listen on."""
    inodes = set()
    for pid in pids:
        try:
            for fd in os.listdir(f'/proc/{pid}/fd'):
                target = os.readlink(f'/proc/{pid}/fd/{fd}')
                if target.startswith('socket:['):
                    inodes.add(target[8:-1])
        except OSError:
            continue
    found = []
    for table in ('/proc/net/tcp', '/proc/net/tcp6'):
        for line in Path(table).read_text().splitlines()[1:]:
            parts = line.split()
            if parts[3] == '0A' and parts[9] in inodes:   # 0A: LISTEN
                found.append(parts[1].split(':')[0])
    return found


def _descendants():
    children, me = {}, os.getpid()
    for entry in os.listdir('/proc'):
        if entry.isdigit():
            try:
                stat = Path(f'/proc/{entry}/stat').read_text()
            except OSError:
                continue
            ppid = int(stat.rsplit(')', 1)[1].split()[1])
            children.setdefault(ppid, []).append(int(entry))
    out, todo = [], [me]
    while todo:
        pid = todo.pop()
        out.append(pid)
        todo += children.get(pid, [])
    return out


def test_a_ray_started_on_demand_listens_on_the_loopback_only_and_stops():
    from reducer_twin.fleet.ray_engine import start_local, stop
    temp_dir = start_local(1)
    try:
        addresses = _listening_sockets(_descendants())
    finally:
        stop(temp_dir)
    loopback = ('0100007F', '0000000000000000FFFF00000100007F', '00000000000000000000000001000000')
    assert addresses and all(a in loopback for a in addresses), addresses
    assert not os.path.exists(temp_dir)


def test_ray_analyses_two_robots_in_parallel_with_the_local_results(tmp_path, capsys):
    bags = []
    for robot, seed in (('r1', 11), ('r2', 31)):
        for k, start in enumerate((0.0, 1500.0)):
            bags.append(str(simulate_bag(tmp_path / f'{robot}_{k}', SimulationSpec(
                robot=robot, start_hours=start, seed=seed, **LIFE)).path))
    bags = [bags[3], bags[0], bags[2], bags[1]]
    runs = {}
    for engine in ('local', 'ray'):
        code, out, err = _run(['analyze', *bags, '--engine', engine, '--jobs', '2', '--store',
                               tmp_path / f'{engine}.db', '--out', tmp_path / engine, '--json'],
                              capsys)
        assert code == 0, err
        code, fleet, err = _run(['fleet', '--store', tmp_path / f'{engine}.db', '--json'],
                                capsys)
        assert code == 0, err
        runs[engine] = json.loads(out), json.loads(fleet)['reducers']
    (local, local_fleet), (remote, ray_fleet) = runs['local'], runs['ray']
    assert (local['engine'], remote['engine']) == ('local', 'ray')
    for name, bag in remote['bags'].items():
        assert bag['joints'] == local['bags'][name]['joints']
        assert set(bag['worker']) == {'node', 'pid'} and bag['worker']['pid'] != os.getpid()
    assert len({b['worker']['pid'] for b in remote['bags'].values()}) >= 2
    assert ray_fleet == local_fleet and [r['bags'] for r in ray_fleet] == [2] * 4


@pytest.mark.parametrize('sig, code, group', STOPS, ids=STOP_IDS)
def test_a_stopped_ray_run_cancels_its_bags_and_leaves_nothing_incomplete(
        tmp_path, sig, code, group):
    # Ray replaced the command's SIGTERM handler (exit 1, a stack dump, no clean-up), and
    # its tasks were killed with the cluster: partial derived bags and locks stayed.
    out, returncode, err = several_bags_stopped(tmp_path, sig, group, '--engine', 'ray')
    said = 'ERROR: terminated (SIGTERM)' if sig == signal.SIGTERM else 'ERROR: interrupted'
    assert returncode == code and said in err and 'Traceback' not in err, err
    written = list(out.iterdir()) if out.exists() else []
    assert out.exists() == bool(written), 'the --out the run made stays only with a bag in it'
    assert [p.name for p in written if p.name.startswith('.')] == [], 'no partial bag or lock'
    assert len(written) < 4, 'every bag was analysed after the stop'
    for bag in written:
        info = yaml.safe_load((bag / 'metadata.yaml').read_text())
        assert info['rosbag2_bagfile_information']['message_count'] > 0
