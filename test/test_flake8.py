"""ament_flake8 over the package's Python: the ROS 2 style as a test."""

from ament_flake8.main import main_with_errors
import pytest

# Everything the package ships or runs; .venv, build, install and log are never
# linted because they are not listed here.
LINTED = ('reducer_twin', 'msg_adapters', 'test', 'bench', 'setup.py')


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8(repo_root, monkeypatch):
    # ament_flake8 walks the working directory for AMENT_IGNORE markers.
    monkeypatch.chdir(repo_root)
    paths = [str(repo_root / name) for name in LINTED if (repo_root / name).exists()]
    rc, errors = main_with_errors(argv=paths)
    assert rc == 0, \
        'Found %d code style errors / warnings:\n' % len(errors) + \
        '\n'.join(errors)
