"""Every package of the source tree is installed (pyproject.toml lists them: a missing one breaks `pip install .`)."""

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_every_package_is_listed_in_pyproject():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for d in ("tofd", "drivers")
             for p in (ROOT / d).rglob("__init__.py")}
    assert found - listed == set()
