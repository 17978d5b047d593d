"""Every package of the source tree (drivers/ through the link tofd/drivers) is installed (pyproject.toml lists
them: a missing one breaks `pip install .`)."""

import os
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_package_is_listed_in_pyproject():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(Path(folder).relative_to(ROOT).parts)
             for folder, _, names in os.walk(ROOT / "tofd", followlinks=True) if "__init__.py" in names}
    assert found - listed == set()
