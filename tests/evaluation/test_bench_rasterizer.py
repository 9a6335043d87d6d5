import pytest

from panorecon.evaluation import bench_rasterizer
from panorecon.splat.rasterize import cpu_backend


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")
def test_cpu_stages_reports_positive_medians():
    out = bench_rasterizer.cpu_stages(size=32, n=300, repeats=2)
    stages = ("projection_forward", "composite_forward", "composite_backward", "projection_backward",
              "reference_projection_forward", "reference_projection_backward")
    assert out["size"] == 32 and out["gaussians"] == 300
    assert all(out[s + "_ms"] > 0 for s in stages)
