"""The micro-benchmarks behind ``panorecon bench`` (``command.py``: the tiny suite and these, against
``benchmarks/baseline.json``): fusion, the MoGe merge on equal inputs, the rasterizer, the fused kernels, the
training step's roofline. Each is also ``python -m panorecon.bench.<name>``, printing JSON."""
