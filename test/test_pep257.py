"""ament_pep257 over the package's Python: docstrings as a test."""

from ament_pep257.main import main
import pytest


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257(repo_root, lint_paths, monkeypatch):
    monkeypatch.chdir(repo_root)
    rc = main(argv=lint_paths)
    assert rc == 0, 'Found code style errors / warnings'
