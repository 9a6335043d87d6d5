"""Build the C++ rasterizer ahead of time: ``python -m panorecon.splat.rasterize.build``."""
import sys

from .cpu_backend import build_dir, load

if __name__ == "__main__":
    ok = load(verbose=False) is not None
    print(f"panorecon cpu rasterizer: {'built' if ok else 'NOT built (the torch backend will be used)'} in {build_dir()}")
    sys.exit(0)
