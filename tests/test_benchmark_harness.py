import json
import subprocess
import sys

from tests.conftest import REPO


def test_list_names_benchmarks():
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "run.py"), "--list"],
                          capture_output=True, text=True, check=True)
    names = {line.split()[0] for line in proc.stdout.splitlines() if line.strip()}
    expected = {p.stem.removeprefix("bench_") for p in (REPO / "benchmarks").glob("bench_*.py")}
    assert names == expected


def test_unknown_benchmark_is_a_usage_error():
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "run.py"), "nope"],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "no benchmark 'nope'" in proc.stderr


def test_figure_json_and_ratio():
    sys.path.insert(0, str(REPO / "benchmarks"))
    from _harness import Figure, format_markdown, ratio

    f = Figure("b", "case", "fps", 300.0, "frames/s", True, target=200.0, peer="x",
               ratio=ratio(300.0, 100.0, higher_is_better=True))
    d = f.as_json()
    assert json.loads(json.dumps(d)) == d
    assert d["ratio"] == 3.0 and d["target"] == 200.0
    assert f.meets_target
    assert ratio(1.0, 4.0, higher_is_better=False) == 4.0
    assert "| case | fps | 300 |" in format_markdown([f])
