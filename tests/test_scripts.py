"""The benchmark and example scripts parse, and every benchmark module has what
``benchmarks/run.py`` calls. No test imports them (running one takes minutes), so a typo in
one would otherwise surface only when someone runs it."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = sorted((ROOT / "benchmarks").glob("*.py")) + sorted((ROOT / "examples").glob("*.py"))


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_script_parses(path):
    compile(path.read_text(), str(path), "exec")


def test_every_benchmark_module_defines_title_and_run():
    benches = sorted((ROOT / "benchmarks").glob("bench_*.py"))
    assert len(benches) >= 10
    missing = []
    for path in benches:
        body = ast.parse(path.read_text()).body
        names = {t.id for node in body if isinstance(node, ast.Assign) for t in node.targets
                 if isinstance(t, ast.Name)}
        runs = [node for node in body if isinstance(node, ast.FunctionDef) and node.name == "run"]
        if "TITLE" not in names:
            missing.append(f"{path.name}: no TITLE")
        if not runs or [a.arg for a in runs[0].args.args][:1] != ["quick"]:
            missing.append(f"{path.name}: no run(quick)")
    assert not missing, "\n".join(missing)
