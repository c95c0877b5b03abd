"""ament_pep257 over the package's Python: docstrings as a test."""

from ament_pep257.main import main
import pytest

LINTED = ('reducer_twin', 'msg_adapters', 'test', 'bench', 'setup.py')


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257(repo_root, monkeypatch):
    monkeypatch.chdir(repo_root)
    paths = [str(repo_root / name) for name in LINTED if (repo_root / name).exists()]
    rc = main(argv=paths)
    assert rc == 0, 'Found code style errors / warnings'
