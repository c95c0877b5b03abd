"""The back stages in a forked worker: what happens when the analysis stops early."""

import subprocess
import sys
import textwrap


def test_a_worker_stopped_after_an_error_lets_the_analysing_process_exit():
    # The analysing process stops the worker at once when it fails (a full disk, a bad
    # message) while more work for it may still be queued. That work is dropped: the
    # queue must not keep the process waiting at exit to write it into a pipe nobody
    # reads (it hung on a 3 MB tmpfs before).
    script = textwrap.dedent("""
        import numpy as np
        from reducer_twin.analysis.stages import WorkerBacks
        backs = WorkerBacks()
        backs._inbox.put(('block',))          # the worker fails on it and stops reading
        for _ in range(64):
            backs.submit('joint_1', 'windows', [np.zeros(65536)])
        backs.terminate()
        print('exited')
    """)
    result = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == 'exited'
