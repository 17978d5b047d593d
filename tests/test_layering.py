"""Imports flow one way: drivers -> features/detection -> pipeline -> commands; Rerun only behind the sink."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def imported_modules(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def modules_under(*parts: str) -> list[Path]:
    base = ROOT.joinpath(*parts)
    return sorted(base.rglob("*.py")) if base.is_dir() else [base.with_suffix(".py")]


def forbidden(path: Path, prefixes: tuple[str, ...]) -> list[str]:
    return sorted(m for m in imported_modules(path) if m.split(".")[0] in prefixes or m.startswith(prefixes))


@pytest.mark.parametrize("path", modules_under("drivers"), ids=lambda p: p.name)
def test_drivers_do_not_import_tofd_or_rerun(path):
    assert forbidden(path, ("tofd", "rerun")) == []


LOWER_LAYERS = [p for part in (("tofd", "features"), ("tofd", "segmentation"), ("tofd", "detect"))
                for p in modules_under(*part) if p.exists()]


@pytest.mark.parametrize("path", LOWER_LAYERS, ids=lambda p: p.name)
def test_features_and_detection_do_not_reach_up(path):
    assert forbidden(path, ("tofd.pipeline", "tofd.commands", "tofd.cli", "rerun")) == []
