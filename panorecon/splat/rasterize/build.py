"""Build the rasterizers ahead of time: ``python -m panorecon.splat.rasterize.build`` (the C++ cpu backend) and
``... build --cuda`` (gsplat's CUDA kernels: its first render compiles them; the seconds are reported here, apart
from any training time)."""

import sys

from .cpu_backend import build_dir, load

if __name__ == "__main__":
    if "--cuda" in sys.argv[1:]:
        from . import gsplat_backend

        if gsplat_backend.available():
            print(f"panorecon gsplat backend: built and ran in {gsplat_backend.build_seconds():.1f} s")
            sys.exit(0)
        print(f"panorecon gsplat backend: NOT available ({gsplat_backend.unavailable_reason()})")
        sys.exit(1)
    ok = load(verbose=False) is not None
    print(
        f"panorecon cpu rasterizer: {'built' if ok else 'NOT built (the torch backend will be used)'} in {build_dir()}"
    )
    sys.exit(0)
