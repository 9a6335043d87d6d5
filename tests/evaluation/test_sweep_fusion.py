import importlib.util
from pathlib import Path

spec = importlib.util.spec_from_file_location("sweep_fusion", Path(__file__).parents[2] / "eval" / "sweep_fusion.py")
sweep = importlib.util.module_from_spec(spec)
spec.loader.exec_module(sweep)


def test_configurations_cover_the_issue():
    names = [c[0] for c in sweep.configurations()]
    assert {f"fibonacci-{n}" for n in (12, 15, 20, 25, 40)} <= set(names)
    assert {"icosahedral", "latlong", "cube", "moge-merge"} <= set(names)
