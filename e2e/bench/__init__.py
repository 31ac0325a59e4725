"""Benchmarks on the bed: ``cluster`` (make bench-cluster), ``scale`` (make bench-scale) and
``real``, the paper's experiment on the paper bed (make bench-real, bench-real-report)."""
