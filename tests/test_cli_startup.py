"""Start-up of the command and of ``import touchloc``: heavy libraries load when first needed."""

import json
import subprocess
import sys
import types

import pytest

HEAVY = ("numba", "llvmlite", "trimesh", "scipy", "matplotlib", "networkx", "dask")


def _modules_after(code):
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys, json; print(json.dumps(sorted(sys.modules)))"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return set(json.loads(out.stdout.splitlines()[-1]))


def _heavy(mods):
    return sorted({m.split(".")[0] for m in mods} & set(HEAVY))


def test_import_touchloc_loads_no_heavy_library():
    assert _heavy(_modules_after("import touchloc")) == []


def test_command_parser_loads_no_heavy_library():
    # what `touchloc --help` and `touchloc --version` import: every subcommand's arguments
    mods = _modules_after("from touchloc.cli import build_parser\nbuild_parser()")
    assert _heavy(mods) == []


def test_a_subpackage_loads_only_what_a_name_needs():
    mods = _modules_after("from touchloc.belief import PoseRegion")
    assert "touchloc.belief.region" in mods
    assert "touchloc.belief.scaling_series" not in mods and "numba" not in mods


@pytest.mark.parametrize("pkg, name", [("belief", "identify"), ("planners", "simulate"), ("dnf", "compare"),
                                       ("mapping", "explore")])
def test_a_name_shared_with_its_module_stays_the_public_object(pkg, name):
    import importlib

    package = importlib.import_module(f"touchloc.{pkg}")
    module = importlib.import_module(f"touchloc.{pkg}.{name}")  # sets the package attribute to the module...
    value = getattr(package, name)
    assert not isinstance(value, types.ModuleType)  # ...which must not replace the public function
    assert value is getattr(module, name)
    exec(f"from touchloc.{pkg} import {name} as imported", ns := {})
    assert ns["imported"] is value


def test_every_public_name_resolves_and_is_listed():
    import importlib

    for pkg in ("models", "belief", "planners", "dnf", "hardware", "mapping", "experiments", "recognition"):
        m = importlib.import_module(f"touchloc.{pkg}")
        for name in m.__all__:
            assert not isinstance(getattr(m, name), types.ModuleType), f"{pkg}.{name}"
        assert set(m.__all__) <= set(dir(m)), pkg
        with pytest.raises(AttributeError, match="no attribute"):
            getattr(m, "no_such_name")
    import touchloc

    assert {"models", "belief", "geometry", "mapping"} <= set(dir(touchloc))
    assert touchloc.models.ProximityModel.__name__ == "ProximityModel"


def test_python_dash_m_touchloc_runs_the_command():
    out = subprocess.run([sys.executable, "-m", "touchloc", "--version"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    import touchloc

    assert out.stdout.strip() == touchloc.__version__
