"""Evaluation: ablation suites (``panorecon ablate``), their statistics and reports (the micro-benchmarks behind
``panorecon bench`` are ``panorecon.bench``)."""
