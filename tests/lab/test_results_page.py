"""docs/RESULTS.md is what bench/results/*.json give, and an evaluation JSON renders its EERs."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "bench" / "results_page.py"


def run_page(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=60)


def test_results_page_is_up_to_date_with_the_bench_json():
    out = run_page("--check")
    assert out.returncode == 0, out.stderr


def test_evaluation_and_bench_json_render_their_numbers(tmp_path):
    results = tmp_path / "results"
    results.mkdir()
    answers = {"scale": 1.0, "found_rate": 0.975, "wrong_rate": 0.0125}
    (results / "evaluation.json").write_text(json.dumps({"seed": 3, "results": {"nfft_range": {
        "overall": {"eer": 0.0123, "scale": [0.1, 0.2], "answers": answers},
        "per_distance": {"0.35": {"eer": 0.0, "answers": answers}, "0.70": {"eer": 0.05, "answers": answers}}}}}))
    (results / "bench_x.json").write_text(json.dumps({"title": "X bench", "cpu_count": 2,
                                                       "rows": [{"scene": "face", "ratio": 3.14159}]}))
    page = tmp_path / "RESULTS.md"
    assert run_page("--results", str(results), "--out", str(page)).returncode == 0
    text = page.read_text()
    assert "| nfft_range | 1.23 | 0 | 5 |" in text  # EER in percent: overall, then per distance
    assert "97.5 / 1.2" in text  # found / wrong
    assert "## X bench" in text and "| face | 3.142 |" in text and "- cpu_count: 2" in text
    assert run_page("--results", str(results), "--out", str(page), "--check").returncode == 0
    page.write_text(text.replace("3.142", "3.000"))
    assert run_page("--results", str(results), "--out", str(page), "--check").returncode == 1
