"""Build the rasterizers ahead of time: ``python -m panorecon.splat.rasterize.build`` (the C++ cpu backend) and
``... build --cuda`` (gsplat's CUDA kernels: its first render compiles them; the seconds are reported here, apart
from any training time)."""

import sys

from .cpu_backend import build_dir, load, unavailable_reason

if __name__ == "__main__":
    if "--cuda" in sys.argv[1:]:
        from . import gsplat_backend

        if gsplat_backend.available():
            print(f"panorecon gsplat backend: built and ran in {gsplat_backend.build_seconds():.1f} s")
            sys.exit(0)
        print(f"panorecon gsplat backend: NOT available ({gsplat_backend.unavailable_reason()})")
        sys.exit(1)
    if load(verbose=False) is not None:
        print(f"panorecon cpu rasterizer: built in {build_dir()}")
    else:
        print(f"panorecon cpu rasterizer: NOT built in {build_dir()}: {unavailable_reason()}; the torch backend runs")
    sys.exit(0)
