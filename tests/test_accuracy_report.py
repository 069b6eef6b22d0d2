"""``benchmarks/accuracy_vs_time.py --quick`` writes its report (its recommendations need each
study's default setting, which a quick run must therefore include)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_quick_mover_study_writes_the_report(tmp_path):
    subprocess.run([sys.executable, str(ROOT / "benchmarks" / "accuracy_vs_time.py"), "--studies", "movers",
                    "--quick", "--output", str(tmp_path)], check=True, capture_output=True, timeout=1200)
    report = (tmp_path / "accuracy_vs_time.md").read_text()
    for row in ("| spring | beam | increments = 30 |", "| linear | beam | increments = 1 |",
                "| yeoh | beam | newton_tol = 1e-10 |"):
        assert row in report
