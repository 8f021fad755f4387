"""Imports go one way only (DESIGN.md): a subpackage imports only the layers below it.

Command-line modules (``_cli.py``) are the application's glue and may reach upwards;
``touchloc.data`` (the bundled meshes) sits beside models and every layer may load from it.
"""

import ast
from pathlib import Path

import touchloc

ALLOWED = {
    "models": set(),
    "data": {"models"},
    "belief": {"models", "data"},
    "planners": {"belief", "models", "data"},
    "mapping": {"models", "belief", "planners", "data"},
    "hardware": {"models", "planners", "data"},
    "dnf": {"models", "belief", "data"},
    "recognition": {"models", "data"},
}


def _imports(path: Path, pkg: str):
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.ImportFrom) or not node.module:
            continue
        if node.level >= 2:                      # from ..belief import x
            yield node.lineno, node.module.split(".")[0]
        elif node.level == 0 and node.module.startswith("touchloc."):
            yield node.lineno, node.module.split(".")[1]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("touchloc."):
                    yield node.lineno, a.name.split(".")[1]


def test_subpackages_import_only_the_layers_below():
    root = Path(touchloc.__file__).parent
    bad = []
    for pkg, allowed in ALLOWED.items():
        files = list((root / pkg).rglob("*.py"))
        assert files, pkg
        for f in files:
            if f.name == "_cli.py":
                continue
            for line, top in _imports(f, pkg):
                if top in ALLOWED and top != pkg and top not in allowed:
                    bad.append(f"{f.relative_to(root)}:{line} imports touchloc.{top}")
    assert not bad, "\n".join(bad)
