"""Evaluation: ablation suites (``panorecon ablate``), their reports, and the benchmarks (``panorecon bench``)."""
