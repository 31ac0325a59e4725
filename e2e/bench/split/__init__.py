"""A split network against whole-module placement on the bed's real nodes (issue 48,
``make bench-split``): ``protocol`` (fixed before the first result), ``run`` (the bed),
``report`` (the table and docs/benchmarks/split.md)."""
