"""
Outputs that never destroy data: inputs read-only, outputs whole or absent, clear limits.

From the outside (the ``reducer-twin`` command, in this process or as a program): an
output that is, contains or lies inside an input is refused and the input stays
byte-identical, ``--overwrite`` or not; a report never replaces a user's own files; a
derived bag replaces only a bag reducer-twin wrote; a run killed with SIGKILL leaves
only a clearly named temporary, which the next run removes; a run that finds its output
locked by another stops at once and says so; two runs racing into one ``--out`` never
leave files of both; a full disk (a real tmpfs, or ENOSPC injected where the files are
written) gives one ``ERROR:`` line with the bytes needed and nothing at the output;
``simulate`` refuses a bag above ``--max-size`` before writing anything.
"""

import hashlib
import os
from pathlib import Path
import shutil
import signal
import subprocess
import time

from cli_runs import program, run_cli, several_bags_stopped, STOP_IDS, stopped_once, STOPS
from full_disk import fill, FillingFile, small_tmpfs
from mcap.reader import make_reader
import pytest
from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.report import write_report
from reducer_twin.analysis.simulate import estimated_bytes, simulate_bag, SimulationSpec
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.io import mcap_array_writer, mcap_writer, outputs
from reducer_twin.io.bag import open_bag
from reducer_twin.io.bag_writer import foreign_bag_entries
from reducer_twin.io.outputs import DiskFull, no_empty_dirs_left, OutputDir, png_text
from reducer_twin.io.outputs import TEMP_TAG, write_file
from reducer_twin.io.rosbag2_compression import _zstd
from small_bags import small_bag
import yaml

pytestmark = pytest.mark.timeout(300, method='thread')

REAL_BAGS = Path(__file__).resolve().parents[2].parent / 'shared' / 'data' / 'rosbag2-jazzy'


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    """Simulate a bag of two joints."""
    return small_bag(tmp_path_factory, 'safe')


@pytest.fixture(scope='module')
def one_joint(tmp_path_factory):
    """Simulate a bag of one joint (fewer derived messages than ``bag``)."""
    return small_bag(tmp_path_factory, 'safe1', 'rec1', joints=1, seed=32)


@pytest.fixture(scope='module')
def result(bag, tmp_path_factory):
    """Analyse the bag, for the report tests."""
    return analyze_bag(bag, tmp_path_factory.mktemp('derived') / 'derived')


def snapshot(root):
    """Return every path under ``root`` with the sha256 of every file (equal: unchanged)."""
    root = Path(root)
    if not root.exists():
        return None
    if root.is_file():
        return hashlib.sha256(root.read_bytes()).hexdigest()
    return {str(p.relative_to(root)): (hashlib.sha256(p.read_bytes()).hexdigest()
                                       if p.is_file() else 'dir')
            for p in sorted(root.rglob('*'))}


def one_error(err):
    """Return the single ``ERROR:`` line of stderr; fail on more, none or a traceback."""
    assert 'Traceback' not in err, err
    lines = [line for line in err.splitlines() if line.startswith('ERROR:')]
    assert len(lines) == 1, err
    return lines[0]


def temporaries(directory):
    """Return the names of reducer-twin's temporaries and locks in ``directory``."""
    return sorted(p.name for p in Path(directory).iterdir() if TEMP_TAG in p.name)


def bag_is_consistent(out):
    """Check metadata.yaml's counts against the .mcap files beside it (mcap library)."""
    info = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    listed = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    found = {}
    files = sorted(out.glob('*.mcap'))
    for path in files:
        with open(path, 'rb') as stream:
            for _, channel, _ in make_reader(stream).iter_messages():
                found[channel.topic] = found.get(channel.topic, 0) + 1
    assert files and found == listed and info['message_count'] == sum(found.values()), (
        f'metadata.yaml lists {listed}, the files hold {found}')


# --------------------------------------------------------------------------- inputs


@pytest.mark.parametrize('where', ['the bag', 'inside the bag', "the bag's parent",
                                   "the bag file's directory"])
@pytest.mark.parametrize('overwrite', [False, True], ids=['', '--overwrite'])
def test_an_out_that_is_contains_or_lies_inside_the_input_is_refused_and_the_input_is_untouched(
        bag, tmp_path, capsys, where, overwrite):
    copy = tmp_path / 'rec'
    shutil.copytree(bag, copy)
    given, out = {
        'the bag': (copy, copy),
        'inside the bag': (copy, copy / 'derived'),
        "the bag's parent": (copy, tmp_path),
        "the bag file's directory": (copy / 'rec_0.mcap', copy),
    }[where]
    before = snapshot(tmp_path)
    code, out_text, err = run_cli(['analyze', given, '--out', out]
                                  + (['--overwrite'] if overwrite else []), capsys)
    assert code == 1
    line = one_error(err)
    assert '--out' in line and 'input bag' in line, line
    assert snapshot(tmp_path) == before, 'nothing written, nothing deleted'


def test_a_report_inside_the_input_or_an_out_holding_the_config_is_refused(
        bag, tmp_path, capsys):
    copy = tmp_path / 'rec'
    shutil.copytree(bag, copy)
    config = tmp_path / 'cfg' / 'twin.yaml'
    config.parent.mkdir()
    config.write_text('twin:\n  window_s: 2.0\n')
    before = snapshot(tmp_path)
    code, _, err = run_cli(['analyze', copy, '--out', tmp_path / 'd', '--report',
                            copy / 'report'], capsys)
    assert code == 1 and '--report' in one_error(err)
    code, _, err = run_cli(['analyze', copy, '--out', config.parent, '--overwrite', '--config',
                            config], capsys)
    assert code == 1 and '--config file' in one_error(err)
    assert snapshot(tmp_path) == before


def test_a_report_and_the_derived_bag_may_not_share_a_place(bag, tmp_path, capsys):
    code, _, err = run_cli(['analyze', bag, '--out', tmp_path / 'd', '--report',
                            tmp_path / 'd' / 'report'], capsys)
    assert code == 1 and 'places of their own' in one_error(err)
    assert not (tmp_path / 'd').exists()


# --------------------------------------------------------------------------- reports


@pytest.mark.parametrize('overwrite', [False, True], ids=['', '--overwrite'])
def test_a_report_never_replaces_a_users_own_files(bag, tmp_path, capsys, overwrite):
    mine = tmp_path / 'mine'
    mine.mkdir()
    (mine / 'index.html').write_text('<!doctype html><p>my own page</p>\n')
    (mine / 'wear.png').write_bytes(b'\x89PNG\r\n\x1a\nmy own plot\n')
    before = snapshot(mine)
    code, _, err = run_cli(['analyze', bag, '--out', tmp_path / 'd', '--report', mine]
                           + (['--overwrite'] if overwrite else []), capsys)
    assert code == 1
    line = one_error(err)
    assert 'did not write' in line and 'index.html' in line and 'wear.png' in line, line
    assert snapshot(mine) == before
    assert temporaries(tmp_path) == []


def test_a_report_goes_into_an_empty_directory_and_replaces_a_previous_report(
        result, tmp_path):
    empty = tmp_path / 'r'
    empty.mkdir()
    page = write_report(result, empty)
    first = snapshot(empty)
    assert page == empty / 'index.html' and 'index.html' in first
    (empty / 'wear.png').write_bytes(b'stale')
    write_report(result, empty)
    again = snapshot(empty)
    # File for file (the page states when it was written, so it may differ by that alone).
    assert set(again) == set(first) and all(again[k] == first[k] for k in first
                                            if k != 'index.html'), 'previous report replaced'
    assert b'stale' not in (empty / 'wear.png').read_bytes()
    assert temporaries(tmp_path) == []
    (empty / 'notes.txt').write_text('mine')
    with pytest.raises(Exception, match='notes.txt'):
        write_report(result, empty)
    assert (empty / 'notes.txt').read_text() == 'mine'


# --------------------------------------------------------------------------- derived bags


def test_overwrite_replaces_a_previous_derived_bag_and_leaves_no_temporary(
        bag, one_joint, tmp_path, capsys):
    out = tmp_path / 'd'
    assert run_cli(['analyze', bag, '--out', out], capsys)[0] == 0
    code, _, err = run_cli(['analyze', one_joint, '--out', out], capsys)
    assert code == 1 and '--overwrite' in one_error(err) and 'overwrite=' not in err
    assert run_cli(['analyze', one_joint, '--out', out, '--overwrite'], capsys)[0] == 0
    with open_bag(out) as derived:
        assert derived.metadata['reducer_twin.joints'] == 'joint_1'
    bag_is_consistent(out)
    assert temporaries(tmp_path) == []


def test_an_empty_out_directory_or_mount_point_receives_the_bag_in_place(
        bag, tmp_path, capsys):
    empty = tmp_path / 'empty'
    empty.mkdir()
    assert run_cli(['analyze', bag, '--out', empty], capsys)[0] == 0
    bag_is_consistent(empty)
    with small_tmpfs(tmp_path / 'mnt', 20_000_000) as mount:
        assert run_cli(['analyze', bag, '--out', mount], capsys)[0] == 0
        assert sorted(p.name for p in mount.iterdir()) == ['metadata.yaml', 'mnt_0.mcap']
        bag_is_consistent(mount)
        assert run_cli(['analyze', bag, '--out', mount, '--overwrite'], capsys)[0] == 0
        assert sorted(p.name for p in mount.iterdir()) == ['metadata.yaml', 'mnt_0.mcap']
    assert temporaries(tmp_path) == []


def test_overwrite_never_replaces_a_bag_reducer_twin_did_not_write(bag, tmp_path, capsys):
    theirs = tmp_path / 'talker'
    shutil.copytree(REAL_BAGS / 'talker', theirs)
    before = snapshot(theirs)
    assert foreign_bag_entries(theirs) == sorted(p.name for p in theirs.iterdir())
    code, _, err = run_cli(['analyze', bag, '--out', theirs, '--overwrite'], capsys)
    assert code == 1 and 'did not write' in one_error(err)
    assert snapshot(theirs) == before


def test_a_run_that_finds_its_out_being_written_stops_at_once_naming_overwrite(
        bag, tmp_path, capsys):
    out = tmp_path / 'd'
    assert run_cli(['analyze', bag, '--out', out], capsys)[0] == 0
    before = snapshot(out)
    holder = OutputDir(out, foreign_bag_entries, 'derived bag', overwrite=True)
    holder.start()   # another run, in the middle of writing
    try:
        code, _, err = run_cli(['analyze', bag, '--out', out, '--overwrite'], capsys)
    finally:
        holder.abort()
    line = one_error(err)
    assert code == 1 and 'another reducer-twin run' in line and '--overwrite' in line, line
    assert f'pid {os.getpid()}' in line
    assert snapshot(out) == before
    assert temporaries(tmp_path) == []


def test_two_overwrite_runs_racing_into_one_out_never_leave_files_of_both(
        bag, one_joint, tmp_path):
    out = tmp_path / 'd'
    subprocess.run(program('analyze', one_joint, '--out', out), check=True,
                   capture_output=True)
    for lead in (0.0, 0.15, 0.0):
        first = subprocess.Popen(program('analyze', bag, '--out', out, '--overwrite'),
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        time.sleep(lead)
        second = subprocess.Popen(program('analyze', one_joint, '--out', out, '--overwrite'),
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        results = [(p.wait(timeout=120), p.stderr.read()) for p in (first, second)]
        for proc in (first, second):
            proc.stderr.close()
        assert any(code == 0 for code, _ in results), results
        for code, err in results:
            if code != 0:
                assert 'another reducer-twin run' in one_error(err), err
        bag_is_consistent(out)
        assert temporaries(tmp_path) == []


def test_without_an_atomic_exchange_the_previous_output_is_replaced_by_two_renames(
        bag, one_joint, tmp_path, monkeypatch):
    out = tmp_path / 'd'
    analyze_bag(bag, out)
    monkeypatch.setattr(outputs, 'exchange', lambda a, b: False)
    analyze_bag(one_joint, out, overwrite=True)
    bag_is_consistent(out)
    with open_bag(out) as derived:
        assert derived.metadata['reducer_twin.joints'] == 'joint_1'
    assert temporaries(tmp_path) == []


def test_a_foreign_file_that_appears_while_writing_stops_the_commit_and_is_kept(tmp_path):
    out = tmp_path / 'd'
    out.mkdir()
    (out / 'metadata.yaml').write_text('rosbag2_bagfile_information:\n  custom_data:\n'
                                       '    reducer_twin.joints: joint_1\n'
                                       '  relative_file_paths: [d_0.mcap]\n')
    (out / 'd_0.mcap').write_bytes(b'old')
    writer = OutputDir(out, foreign_bag_entries, 'derived bag', overwrite=True)
    (writer.start() / 'd_0.mcap').write_bytes(b'new')
    (out / 'mine.txt').write_text('mine')
    with pytest.raises(InvalidParameter, match='mine.txt'):
        writer.commit()
    assert (out / 'd_0.mcap').read_bytes() == b'old' and (out / 'mine.txt').exists()
    assert temporaries(tmp_path) == []


def test_analyze_killed_mid_write_leaves_a_named_temporary_the_next_run_removes(tmp_path):
    rec = tmp_path / 'rec'
    simulate_bag(rec, SimulationSpec(hours=150.0, aging_factor=3600.0, joints=1, seed=5))
    out = tmp_path / 'd'
    proc = subprocess.Popen(program('analyze', rec, '--out', out, '--stage-process', 'no'),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    partial = None
    try:
        deadline = time.monotonic() + 120
        while partial is None and proc.poll() is None and time.monotonic() < deadline:
            for tmp in tmp_path.glob(f'.d.{TEMP_TAG}-incomplete-*'):
                files = [f for f in tmp.glob('*.mcap') if f.stat().st_size > 0]
                partial = files[0] if files else None
            time.sleep(0.001)
        assert partial is not None, 'the run ended before a partial derived bag was seen'
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    assert not out.exists(), 'nothing at --out'
    assert partial.parent.name == f'.d.{TEMP_TAG}-incomplete-{proc.pid}'
    subprocess.run(program('analyze', rec, '--out', out), check=True, capture_output=True)
    bag_is_consistent(out)
    assert temporaries(tmp_path) == [], 'the stale temporary and the lock are gone'


@pytest.mark.parametrize('sig, code, said', [
    (signal.SIGTERM, 143, 'ERROR: terminated (SIGTERM)'),
    (signal.SIGINT, 130, 'ERROR: interrupted'),
], ids=['SIGTERM (a service stopped)', 'SIGINT (Ctrl-C)'])
def test_analyze_stopped_by_a_signal_mid_write_leaves_nothing_at_or_beside_out(
        tmp_path, sig, code, said):
    # SIGTERM left the partial derived bag and the lock beside --out (7 MB).
    rec = tmp_path / 'rec'
    simulate_bag(rec, SimulationSpec(hours=150.0, aging_factor=3600.0, joints=1, seed=5))
    before = snapshot(rec)
    out = tmp_path / 'd'
    returncode, err = stopped_once(
        program('analyze', rec, '--out', out), sig,
        lambda: any(f.stat().st_size > 0 for tmp in tmp_path.glob(f'.d.{TEMP_TAG}-incomplete-*')
                    for f in tmp.glob('*.mcap')), 'a partial derived bag')
    assert returncode == code and said in err and 'Traceback' not in err, err
    assert not out.exists() and temporaries(tmp_path) == [], 'no bag, temporary or lock'
    assert snapshot(rec) == before


@pytest.mark.parametrize('sig, code, group', STOPS, ids=STOP_IDS)
def test_analyze_of_several_bags_stopped_stops_every_bag_and_starts_no_other(
        tmp_path, sig, code, group):
    # The bags' process pool ran every bag queued before the stop: four bags were all
    # analysed and written after Ctrl-C or SIGTERM.
    # The --out it made stayed, empty, when no bag was finished before the stop.
    out, returncode, err = several_bags_stopped(tmp_path, sig, group)
    assert returncode == code and 'Traceback' not in err, err
    written = sorted(p.name for p in out.iterdir()) if out.exists() else []
    assert out.exists() == bool(written), 'the --out the run made stays only with a bag in it'
    assert [name for name in written if TEMP_TAG in name] == [], 'no partial bag or lock'
    assert set(written) <= {'rec0', 'rec1'}, f'bags queued at the stop were analysed: {written}'
    for name in written:
        bag_is_consistent(out / name)


@pytest.mark.parametrize('store', [False, True], ids=['bags', 'robots into a fleet store'])
def test_a_bag_process_killed_is_one_error_per_bag_not_a_traceback(tmp_path, store):
    # A pool worker killed (the kernel's out-of-memory killer) broke the pool: the
    # command ended in a BrokenProcessPool traceback.
    bags = []
    for k in range(3):
        bags.append(tmp_path / f'rec{k}')
        simulate_bag(bags[-1], SimulationSpec(hours=150.0, aging_factor=3600.0, joints=1,
                                              seed=5, robot=f'r{k}'))
    out = tmp_path / 'd'
    extra = ['--store', tmp_path / 'fleet.db'] if store else []
    proc = subprocess.Popen(program('analyze', *bags, '--out', out, '--jobs', '2', *extra),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        workers = []
        while not workers and proc.poll() is None and time.monotonic() < deadline:
            if out.is_dir() and any(out.glob('.rec*')):
                children = Path(f'/proc/{proc.pid}/task/{proc.pid}/children').read_text()
                workers = [int(pid) for pid in children.split()]
            time.sleep(0.001)
        assert workers, 'the run ended before its bags were being written'
        os.kill(workers[0], signal.SIGKILL)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
        proc.wait()
    lines = err.splitlines()
    assert proc.returncode == 1 and 'Traceback' not in err, err
    assert len(lines) == 3 and all(line.startswith('ERROR: ') and 'not analysed' in line
                                   and 'out of memory' in line for line in lines), err
    assert sorted(line.split(':')[1].strip() for line in lines) == sorted(map(str, bags))


@pytest.mark.parametrize('sig, code', [(signal.SIGTERM, 143), (signal.SIGINT, 130)],
                         ids=['SIGTERM', 'SIGINT'])
def test_analyze_stopped_while_decompressing_a_recording_leaves_no_copy_behind(
        tmp_path, sig, code):
    # A file-compressed recording is decompressed into TMPDIR before it is read; stopped
    # then, the copy (here 256 MiB) stayed there.
    rec = tmp_path / 'rec'
    rec.mkdir()
    compressor = _zstd.ZstdCompressor()
    with open(rec / 'rec_0.mcap.zstd', 'wb') as stream:
        for _ in range(4):
            stream.write(compressor.compress(bytes(1 << 26)))
        stream.write(compressor.flush())
    before = snapshot(rec)
    scratch = tmp_path / 'scratch'
    scratch.mkdir()
    returncode, err = stopped_once(
        program('analyze', rec, '--out', tmp_path / 'd'), sig,
        lambda: any(f.stat().st_size > 0 for f in scratch.glob('reducer-twin-bag-*/*')),
        'its copy', env={**os.environ, 'TMPDIR': str(scratch)})
    assert returncode == code and 'Traceback' not in err, err
    assert list(scratch.iterdir()) == [], 'no decompressed copy left'
    assert snapshot(rec) == before and not (tmp_path / 'd').exists()

# --------------------------------------------------------------------------- full disks


def test_a_full_disk_under_analyze_is_one_error_with_the_bytes_and_nothing_at_out(
        bag, tmp_path, capsys):
    with small_tmpfs(tmp_path / 'disk', 100_000) as disk:
        code, _, err = run_cli(['analyze', bag, '--out', disk / 'out'], capsys)
        line = one_error(err)
        assert code == 1 and 'no space left' in line and 'bytes' in line, line
        assert str(disk / 'out') in line
        assert sorted(p.name for p in disk.iterdir()) == [], 'no bag, temporary or lock'


def test_a_full_disk_under_analyze_of_several_bags_leaves_no_directory_the_run_made(
        bag, tmp_path, capsys):
    # Every bag failed, and the --out directory (and its parent) the run had made stayed,
    # empty.
    other = tmp_path / 'other'
    shutil.copytree(bag, other)
    with small_tmpfs(tmp_path / 'disk', 100_000) as disk:
        code, _, err = run_cli(['analyze', bag, other, '--out', disk / 'new' / 'out'], capsys)
        lines = [line for line in err.splitlines() if line.startswith('ERROR:')]
        assert code == 1 and len(lines) == 2 and 'Traceback' not in err, err
        assert all('no space left' in line for line in lines), err
        assert list(disk.iterdir()) == [], 'no bag, temporary, lock or directory'


def test_directories_made_above_outputs_go_when_left_empty_and_stay_with_anything_in_them(
        tmp_path):
    kept = tmp_path / 'kept'
    kept.mkdir()
    targets = [tmp_path / 'a' / 'b' / 'out', kept / 'c' / 'out', tmp_path / 'd' / 'out']
    with pytest.raises(KeyboardInterrupt):
        with no_empty_dirs_left(targets):
            for target in targets:
                target.parent.mkdir(parents=True)
            (tmp_path / 'd' / 'note.txt').write_text('a file of somebody else')
            raise KeyboardInterrupt
    assert sorted(p.name for p in tmp_path.iterdir()) == ['d', 'kept']
    assert list(kept.iterdir()) == [] and (tmp_path / 'd' / 'note.txt').exists()
    with no_empty_dirs_left(targets[:1]):
        targets[0].mkdir(parents=True)
    assert targets[0].is_dir(), 'a finished output and the directories above it stay'


# --------------------------------------------------------------------------- single files


def _png(software):
    """Return a small PNG as matplotlib writes it, with ``Software`` set."""
    import io
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig = plt.figure(figsize=(1, 1))
    buffer = io.BytesIO()
    fig.savefig(buffer, format='png', metadata={'Software': software})
    plt.close(fig)
    return buffer.getvalue()


def _ours(path):
    return png_text(path).get('Software') == 'ours'


def test_a_file_output_replaces_only_its_own_kind_and_leaves_no_temporary(tmp_path):
    target = tmp_path / 'plot.png'
    write_file(target, _png('ours'), _ours, 'the plot', '--plot')
    write_file(target, _png('ours') + b'', _ours, 'the plot', '--plot')   # replaced
    assert _ours(target) and [p.name for p in tmp_path.iterdir()] == ['plot.png']
    theirs = tmp_path / 'theirs.png'
    theirs.write_bytes(_png('Matplotlib version 3'))
    before = theirs.read_bytes()
    with pytest.raises(InvalidParameter, match='theirs.png exists and was not written by '
                                               'reducer-twin; it is never replaced'):
        write_file(theirs, _png('ours'), _ours, 'the plot', '--plot')
    assert theirs.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ['plot.png', 'theirs.png']


def test_a_file_output_removes_what_a_killed_writer_left_and_nothing_of_a_live_one(tmp_path):
    target = tmp_path / 'plot.png'
    stale = tmp_path / f'.plot.png.{TEMP_TAG}-incomplete-999999999'   # beyond any pid
    live = tmp_path / f'.plot.png.{TEMP_TAG}-incomplete-1'     # pid 1 is always there
    stale.write_bytes(b'partial')
    live.write_bytes(b'partial')
    write_file(target, _png('ours'), _ours, 'the plot', '--plot')
    assert sorted(p.name for p in tmp_path.iterdir()) == [live.name, 'plot.png']


def test_a_full_disk_under_a_file_output_is_one_error_and_leaves_nothing(tmp_path):
    with small_tmpfs(tmp_path / 'disk', 100_000) as disk:
        with pytest.raises(DiskFull, match=r'no space left on device writing the plot --plot '
                                           r'.*needs about'):
            write_file(disk / 'plot.png', bytes(300_000), _ours, 'the plot', '--plot')
        assert list(disk.iterdir()) == []


def test_a_full_disk_under_simulate_is_refused_first_or_reported_with_nothing_left(
        tmp_path, capsys):
    spec = SimulationSpec(hours=400.0, aging_factor=36_000.0, joints=1, seed=2)
    with small_tmpfs(tmp_path / 'disk', 1_000_000) as disk:
        code, _, err = run_cli(['simulate', '--out', disk / 'sim', '--hours', 400,
                                '--aging-factor', 36_000, '--seed', 2], capsys)
        line = one_error(err)
        assert code == 1 and f'{estimated_bytes(spec):,} bytes' in line, line
        assert list(disk.iterdir()) == []
        # Past the estimate (as when something else fills the disk meanwhile).
        with pytest.raises(DiskFull, match='no space left.*simulated bag'):
            simulate_bag(disk / 'sim', spec)
        assert list(disk.iterdir()) == []


def test_a_full_disk_under_the_report_is_one_error_and_the_directory_stays_absent(
        result, tmp_path):
    with small_tmpfs(tmp_path / 'disk', 1_000_000) as disk:
        filler = fill(disk, leave=20_000)
        with pytest.raises(DiskFull, match=r'no space left on device writing the report'
                                           r'.*needs about'):
            write_report(result, disk / 'report')
        assert sorted(p.name for p in disk.iterdir()) == [filler.name]


@pytest.mark.parametrize('module', [mcap_writer, mcap_array_writer],
                         ids=['library framing', 'fast'])
def test_enospc_at_the_file_write_edge_leaves_nothing_at_the_bag_directory(
        bag, tmp_path, monkeypatch, module):
    monkeypatch.setattr(module, 'open', FillingFile(200_000).opener, raising=False)
    framing = 'library' if module is mcap_writer else 'fast'
    from reducer_twin.analysis import pipeline
    if framing == 'fast':
        monkeypatch.setattr(pipeline, 'BagDirWriter', _fast_writer)
    with pytest.raises(DiskFull, match=r'no space left on device writing the derived bag '
                                       r'.*needs about'):
        analyze_bag(bag, tmp_path / 'out')
    assert list(tmp_path.iterdir()) == []


def _fast_writer(*args, **kwargs):
    from reducer_twin.io.bag_writer import BagDirWriter
    return BagDirWriter(*args, framing='fast', **kwargs)


# --------------------------------------------------------------------------- size guard


def test_simulate_refuses_a_bag_above_max_size_before_writing_anything(tmp_path, capsys):
    code, _, err = run_cli(['simulate', '--out', tmp_path / 'huge', '--hours', 100_000,
                            '--aging-factor', 3600, '--joints', 6, '--rate-hz', 1000], capsys)
    line = one_error(err)
    assert code == 1 and '57.2 GB' in line and '--max-size 5.0 GB' in line, line
    assert list(tmp_path.iterdir()) == []
    code, _, err = run_cli(['simulate', '--out', tmp_path / 'small', '--hours', 100,
                            '--max-size', '1M'], capsys)
    assert code == 1 and '--max-size 1.0 MB' in one_error(err)
    code, _, err = run_cli(['simulate', '--out', tmp_path / 'x', '--max-size', '5 parsecs'],
                           capsys)
    assert code == 2 and 'parsecs' in one_error(err)


@pytest.mark.parametrize('layout', ['combined', 'split'])
def test_the_size_estimate_is_within_two_percent_of_the_written_bag(tmp_path, layout):
    spec = SimulationSpec(hours=100.0, aging_factor=36_000.0, joints=3, seed=1, layout=layout)
    out = simulate_bag(tmp_path / 'sim', spec).path
    written = sum(p.stat().st_size for p in out.iterdir())
    assert estimated_bytes(spec) == pytest.approx(written, rel=0.02)
