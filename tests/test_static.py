"""The static checks pass: ruff over the package and the tests, mypy over the files that
pyproject.toml's ``[tool.mypy]`` lists (both configured there)."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _check(module: str, *args: str) -> None:
    if importlib.util.find_spec(module) is None:
        pytest.skip(f"{module} is not installed (pip install -e '.[test]')")
    done = subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, f"{module} {' '.join(args)} failed:\n{done.stdout}{done.stderr}"


# Starts a process, yet left in the quick loop: ruff takes a tenth of a second.
def test_ruff_passes():
    _check("ruff", "check", "--no-cache", "icefarm", "tests")


@pytest.mark.slow  # starts mypy: about 10 s without its cache (.mypy_cache), under a second with it
def test_mypy_passes():
    _check("mypy")
