"""The layer contracts (import-linter, pyproject.toml), mypy over the package tofd (drivers/ as tofd.drivers) and ruff
hold for the tree."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent


def run_tool(name: str, *args: str) -> subprocess.CompletedProcess:
    exe = BIN / name if (BIN / name).exists() else shutil.which(name)
    if exe is None:
        pytest.fail(f"{name} is not installed (pip install '.[test]')")
    return subprocess.run([str(exe), *args], cwd=ROOT, capture_output=True, text=True, timeout=300)


def test_import_layers_hold():
    out = run_tool("lint-imports")
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    assert "broken" in out.stdout and " 0 broken" in out.stdout


def test_mypy_checks_every_module_of_tofd_with_its_drivers():
    out = run_tool("mypy")
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    modules = sum(name.endswith(".py") for _, _, names in os.walk(ROOT / "tofd", followlinks=True) for name in names)
    assert f"no issues found in {modules} source files" in out.stdout, out.stdout[-500:]


def test_ruff_is_clean():
    out = run_tool("ruff", "check", ".")
    assert out.returncode == 0, out.stdout[-3000:]
