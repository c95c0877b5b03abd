"""ament_flake8 over the package's Python: the ROS 2 style as a test."""

from ament_flake8.main import main_with_errors
import pytest


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8(repo_root, lint_paths, monkeypatch):
    # ament_flake8 walks the working directory for AMENT_IGNORE markers.
    monkeypatch.chdir(repo_root)
    rc, errors = main_with_errors(argv=lint_paths)
    assert rc == 0, \
        'Found %d code style errors / warnings:\n' % len(errors) + \
        '\n'.join(errors)
