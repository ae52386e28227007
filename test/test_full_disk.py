"""`sofia run` and `sofia compare` onto a full or a read-only disk: one line on stderr, exit 3 (full) or 2
(read-only), no traceback, no half-written file (summary.json whole or absent), no node log folder left.

The disks are real: a tmpfs of a few hundred KiB mounted for the test (the sandbox runs the tests as
root), remounted read-only, or filled to the last byte by a filler file. Where mount is not permitted,
the bag's disk filling up is simulated in the MCAP file's writes instead, and the read-only and
--processes cases are skipped (they need a real mount). Which output the disk refuses first: the bag,
summary.json or a side file (its fsync fails with ENOSPC: the bag fits, the summary does not),
compare's --json or --report. The cases are generated: run mode x campaign x disk x output.
"""

import errno
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from graph_startup import STARTUP_RERUNS
from sofia_ros.cli import main

ROOT = Path(__file__).resolve().parents[1]
TRUTH = str(ROOT / 'config' / 'truth' / 'nominal.yaml')
MODEL = str(ROOT / 'config' / 'model' / 'nominal.yaml')
#: A disk this small fills within the first seconds of sim of every campaign (about 8000 messages).
SMALL_DISK_KIB = 300

#: Each campaign reduced to seconds of wall time.
CAMPAIGNS = {
    'alignment': ['alignment', '--repetitions', '2', '--verification-repetitions', '1'],
    'star-hop': ['star-hop', '--observations', '1-2', '--no-follow-times', '--hold-s', '5'],
    'gyro-stability': ['gyro-stability', '--case', 'TC-1', '--hours', '0.01'],
}
MODES = {'direct': ['--direct'], 'default': [], 'all-dds': ['--all-dds'], 'processes': ['--processes']}
#: gyro-stability records the gyro box alone: only its default mode runs.
GRAPH_CAMPAIGNS = ('alignment', 'star-hop')


def _mount_refusal():
    """Why a tmpfs cannot be mounted here (not root, no CAP_SYS_ADMIN), or None when it can."""
    with tempfile.TemporaryDirectory(prefix='sofia_mount_probe_') as folder:
        try:
            subprocess.run(['mount', '-t', 'tmpfs', '-o', 'size=64k', 'tmpfs', folder], check=True,
                           capture_output=True, text=True, timeout=10)
        except (OSError, subprocess.SubprocessError) as err:
            return f'mounting a tmpfs is not permitted here ({getattr(err, "stderr", "") or err})'
        subprocess.run(['umount', folder], check=True, timeout=10)
    return None


MOUNT_REFUSAL = _mount_refusal()
needs_mount = pytest.mark.skipif(MOUNT_REFUSAL is not None, reason=str(MOUNT_REFUSAL))


class Disk:
    """A small tmpfs at ``path`` for one test: filled, remounted read-only, unmounted at the end."""

    def __init__(self, path, size_kib):
        self.path = path
        path.mkdir()
        subprocess.run(['mount', '-t', 'tmpfs', '-o', f'size={size_kib}k', 'tmpfs', str(path)], check=True, timeout=10)

    def fill(self):
        """Take every free byte with a filler file (kept: it is not an output of the command)."""
        with open(self.path / 'filler', 'wb', buffering=0) as filler:
            try:
                while True:
                    filler.write(b'\0' * 4096)
            except OSError as err:
                assert err.errno == errno.ENOSPC

    def read_only(self):
        subprocess.run(['mount', '-o', 'remount,ro', str(self.path)], check=True, timeout=10)

    def unmount(self):
        subprocess.run(['umount', '-l', str(self.path)], check=True, timeout=10)

    def outputs(self):
        """Every name on the disk but the filler: what the command left behind."""
        return sorted(str(path.relative_to(self.path)) for path in self.path.rglob('*') if path.name != 'filler')


@pytest.fixture
def disk(tmp_path):
    """A SMALL_DISK_KIB tmpfs (the test is skipped without mount); unmounted after the test."""
    if MOUNT_REFUSAL is not None:
        pytest.skip(MOUNT_REFUSAL)
    mounted = Disk(tmp_path / 'disk', SMALL_DISK_KIB)
    yield mounted
    mounted.unmount()


def _fail_fsync_of(monkeypatch, name):
    """The disk refuses the file whose name starts ``.NAME.`` (atomic_output's temporary) at its fsync: ENOSPC."""
    real_fsync = os.fsync

    def fsync(descriptor):
        if Path(os.readlink(f'/proc/self/fd/{descriptor}')).name.startswith(f'.{name}.'):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_fsync(descriptor)

    monkeypatch.setattr(os, 'fsync', fsync)


def _fail_mcap_writes_after(monkeypatch, limit):
    """Without a tmpfs: the bag's MCAP file takes ``limit`` bytes, then every write fails with ENOSPC."""
    from sofia_ros.bag.mcap_storage import CheckedMcapStorage

    real_emit = CheckedMcapStorage._emit
    written = {}

    def emit(storage, data):
        written[storage] = written.get(storage, 0) + len(data)
        if written[storage] > limit:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_emit(storage, data)

    monkeypatch.setattr(CheckedMcapStorage, '_emit', emit)


def _is_progress(line):
    """A status line of `sofia run` (cli._Progress), not an error."""
    return line.startswith(('sim ', 'running: ')) or line.strip() == ''


def assert_one_line_error(code, stderr, expected_code, *fragments):
    """Exit ``expected_code``, one `sofia: error:` line (besides progress lines) holding every fragment."""
    assert 'Traceback' not in stderr, stderr
    lines = [line for line in stderr.replace('\r', '\n').splitlines() if not _is_progress(line)]
    assert len(lines) == 1 and lines[0].startswith('sofia: error: '), stderr
    assert code == expected_code, stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def assert_summary_whole_or_absent(bag):
    """summary.json is valid JSON or not there; no temporary file of atomic_output is left."""
    if (bag / 'summary.json').exists():
        json.loads((bag / 'summary.json').read_text())
    if bag.is_dir():
        assert not [path.name for path in bag.iterdir() if path.name.startswith('.')], list(bag.iterdir())


def run_in_process(capfd, args):
    """cli.main(args) in this process: its exit code and stderr."""
    capfd.readouterr()
    code = main(args)
    return code, capfd.readouterr().err


def _run_args(campaign, mode, bag):
    name, *options = CAMPAIGNS[campaign]
    return ['run', name, '--truth', TRUTH, '--bag', str(bag), *options, *MODES[mode]]


def _graph_folders(private_tmp):
    return list(private_tmp.glob('sofia_graph_*'))


# --- sofia run: the bag fills the disk ----------------------------------------------------------------------

IN_PROCESS_MODES = ('direct', 'default', 'all-dds')
BAG_FILLS = [(campaign, mode) for campaign in GRAPH_CAMPAIGNS for mode in IN_PROCESS_MODES] + [('gyro-stability',
                                                                                                  'default')]


@pytest.mark.parametrize('campaign,mode', BAG_FILLS)
def test_a_bag_that_fills_the_disk_is_one_line_exit_3_naming_what_it_keeps(tmp_path, capfd, monkeypatch, campaign,
                                                                           mode):
    if MOUNT_REFUSAL is None:
        folder = Disk(tmp_path / 'disk', SMALL_DISK_KIB)
    else:
        folder = None
        _fail_mcap_writes_after(monkeypatch, SMALL_DISK_KIB * 1024)
    bag = (folder.path if folder else tmp_path) / 'bag'
    try:
        code, stderr = run_in_process(capfd, _run_args(campaign, mode, bag))
        # On the full tmpfs summary.json has no room either; where only the MCAP file is refused, it has.
        summary = 'summary.json not written either' if folder else 'summary.json: "stopped": "fault"'
        line = assert_one_line_error(code, stderr, 3, f'cannot write bag {bag}: disk full', 'messages kept',
                                     f'`sofia recover {bag}` restores them', summary)
        assert_summary_whole_or_absent(bag)
        assert not (bag / 'metadata.yaml').exists()
        if campaign == 'alignment' and mode == 'direct':
            # "at least N messages kept" is true: sofia recover (on a disk with room) restores N or more.
            kept = int(line.split('at least ')[1].split(' ')[0])
            monkeypatch.undo()  # the recovered bag is written to a disk with room
            copy = tmp_path / 'copy'
            shutil.copytree(bag, copy)
            code, _ = run_in_process(capfd, ['recover', str(copy)])
            assert code == 0
            from sofia_ros.bag import BagReader

            with BagReader(tmp_path / 'copy_recovered') as recovered:
                assert kept <= sum(topic.count for topic in recovered.topics) < kept + 2000
    finally:
        if folder:
            folder.unmount()


def test_a_graph_stopped_by_a_full_disk_leaves_nothing_in_the_ros_domain(disk, capfd):
    """Its nodes destroyed though an exception ended the run: else a later graph of this process in the domain got
    the old clock's /sim/stop and stopped at once (the --processes case below, run after these, did)."""
    import time

    import rclpy

    code, _ = run_in_process(capfd, _run_args('alignment', 'all-dds', disk.path / 'bag'))
    assert code == 3
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        probe = rclpy.create_node('full_disk_probe', context=context)
        deadline = time.monotonic() + 3.0  # local discovery takes well under a second
        while time.monotonic() < deadline:
            assert probe.get_publishers_info_by_topic('/sim/stop') == []
            time.sleep(0.2)
        probe.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize('campaign,mode', [('alignment', 'direct'), ('alignment', 'default'), ('star-hop', 'direct'),
                                           ('star-hop', 'all-dds'), ('gyro-stability', 'default')])
def test_a_disk_full_from_the_start_is_one_line_exit_3_and_no_bag(disk, capfd, campaign, mode):
    disk.fill()
    bag = disk.path / 'bag'
    code, stderr = run_in_process(capfd, _run_args(campaign, mode, bag))
    assert_one_line_error(code, stderr, 3, f'cannot write {bag}: disk full; free space or write elsewhere')
    assert disk.outputs() == []


@pytest.mark.parametrize('campaign,mode', [(campaign, mode) for campaign in GRAPH_CAMPAIGNS for mode in MODES]
                         + [('gyro-stability', 'default')])
def test_a_read_only_disk_is_one_line_exit_2_before_any_node_starts(disk, private_tmp, capfd, campaign, mode):
    disk.read_only()
    bag = disk.path / 'runs' / 'bag'
    code, stderr = run_in_process(capfd, _run_args(campaign, mode, bag))
    assert_one_line_error(code, stderr, 2, f'cannot write {bag}: read-only file system')
    assert disk.outputs() == []
    assert _graph_folders(private_tmp) == []


@needs_mount
@STARTUP_RERUNS
def test_processes_mode_on_a_full_disk_reports_the_recorders_disk_full_and_leaves_no_log_folder(disk, private_tmp):
    """The recorder process meets ENOSPC: its own error line reaches the launcher (was: 'the recorder node exited
    with code 1' after 80 lines of traceback, the node logs kept in /tmp/sofia_graph_*)."""
    bag = disk.path / 'bag'
    result = subprocess.run([sys.executable, '-m', 'sofia_ros.cli', *_run_args('alignment', 'processes', bag)],
                            capture_output=True, text=True, timeout=240)
    assert_one_line_error(result.returncode, result.stderr, 3, f'cannot write bag {bag}: disk full',
                          'messages kept', f'`sofia recover {bag}`')
    assert 'exited with code' not in result.stderr and 'sofia_graph_' not in result.stderr
    assert_summary_whole_or_absent(bag)
    assert _graph_folders(private_tmp) == []


def test_the_launcher_takes_the_recorders_own_error_line_and_removes_the_node_logs(tmp_path, monkeypatch):
    """The launcher's side of the case above, with stand-ins: a recorder that logged its error and exited 2."""
    from sofia_ros.nodes import launch

    workdir = tmp_path / 'sofia_graph_stand_in'
    workdir.mkdir()
    (workdir / 'recorder.log').write_text(
        "[FATAL] [recorder]: Exception in 'subscriptions' callback: cannot write bag B: disk full\n"
        'Traceback (most recent call last):\n'
        'sofia_ros.errors.OutputError: cannot write bag B: disk full\n'
        'recorder: error: cannot write bag B: disk full; free space or write elsewhere; at least 7 messages kept\n')
    processes = {'clock': subprocess.Popen([sys.executable, '-c', 'raise SystemExit(0)']),
                 'recorder': subprocess.Popen([sys.executable, '-c', 'raise SystemExit(2)'])}
    graph = launch.GraphProcesses(processes, workdir, bag_path=tmp_path / 'bag')
    monkeypatch.setattr(launch, 'start_graph_processes', lambda parameters, bag_path: graph)
    with pytest.raises(launch.RecorderError, match=r'^cannot write bag B: disk full; free space or write elsewhere; '
                                                   r'at least 7 messages kept$'):
        launch.run_graph_in_processes({'max_sim_s': 10.0}, tmp_path / 'bag', timeout_s=50)
    assert not workdir.exists()


# --- sofia run: the bag fits, summary.json or a side file does not -------------------------------------------

SHORT_RUNS = {
    'alignment': ['--max-sim-s', '2', '--direct'],
    'star-hop': ['--direct'],
    'gyro-stability': [],
}
#: The star hop flies a whole (short) sequence: one case of it is enough.
LATE_FILES = [(campaign, name) for campaign in SHORT_RUNS for name in ('summary.json', 'truth.yaml')
              if (campaign, name) != ('star-hop', 'truth.yaml')]


@pytest.mark.parametrize('campaign,name', LATE_FILES)
def test_a_file_written_after_the_bag_on_a_full_disk_is_one_line_exit_3_and_never_half_there(
        tmp_path, capfd, monkeypatch, campaign, name):
    _fail_fsync_of(monkeypatch, name)
    bag = tmp_path / 'bag'
    args = _run_args(campaign, 'default', bag) + SHORT_RUNS[campaign]
    if campaign == 'star-hop':
        args[args.index('5')] = '1'  # --hold-s 1: the shortest star hop
    code, stderr = run_in_process(capfd, args)
    assert_one_line_error(code, stderr, 3, f'cannot write {bag / name}: disk full')
    assert not (bag / name).exists()
    assert_summary_whole_or_absent(bag)
    assert (bag / 'metadata.yaml').exists()  # the bag itself was finished


# --- sofia compare --json / --report -------------------------------------------------------------------------

@pytest.fixture(scope='module')
def compared(campaign_bags):
    """A reduced alignment bag and its comparison, computed once: the cases below only write it."""
    from sofia_ros.compare.run import compare_bag
    from sofia_ros.config import load_effect_config

    bag = campaign_bags.reduced_alignment()
    return bag, compare_bag(bag, load_effect_config(MODEL))


COMPARE_OUTPUTS = {'json': ['--json', 'out/compare.json'], 'report': ['--report', 'out/report'],
                   'json+report': ['--json', 'out/compare.json', '--report', 'out/report']}
COMPARE_CASES = [(outputs, state) for outputs in COMPARE_OUTPUTS for state in ('full', 'read-only')]


@pytest.mark.parametrize('outputs,state', COMPARE_CASES)
def test_compare_outputs_onto_a_full_or_read_only_disk_are_one_line_and_never_half_written(
        disk, capfd, monkeypatch, compared, outputs, state):
    bag, result = compared
    monkeypatch.setattr('sofia_ros.compare.run.compare_bag', lambda *args, **kwargs: result)
    (disk.path / 'out').mkdir()
    if state == 'full':
        disk.fill()
    else:
        disk.read_only()
    args = [str(disk.path / value) if value.startswith('out/') else value for value in COMPARE_OUTPUTS[outputs]]
    code, stderr = run_in_process(capfd, ['compare', str(bag), '--model', MODEL, *args])
    # The report is written before the JSON, so that a report the disk refuses leaves no JSON behind.
    first = Path(args[args.index('--report') + 1] if '--report' in args else args[1])
    reason = 'disk full' if state == 'full' else 'read-only file system'
    assert_one_line_error(code, stderr, 3 if state == 'full' else 2, f'cannot write {first}: {reason}')
    assert disk.outputs() == ['out']

