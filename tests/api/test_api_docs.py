"""docs/API.md: every python code block runs, in order, in one namespace (the examples build on each other)."""

import re
from pathlib import Path

import pytest

API_DOC = Path(__file__).resolve().parents[2] / "docs" / "API.md"


def code_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


@pytest.mark.slow
def test_every_example_in_the_api_doc_runs(tmp_path, monkeypatch, capsys):
    blocks = code_blocks(API_DOC.read_text())
    assert len(blocks) >= 8
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for i, block in enumerate(blocks):
        source = block.replace("/tmp/tofd_api_example_model.json", str(tmp_path / "model.json"))
        exec(compile(source, f"{API_DOC.name} block {i + 1}", "exec"), namespace)  # noqa: S102
    out = capsys.readouterr().out
    assert "LoG at the apex" in out and "too coarse" in out and "short of the filters' band" in out
    assert (tmp_path / "model.json").exists()
