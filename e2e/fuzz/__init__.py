"""Fuzzed custom resources drawn from the CRDs' own schemas (issue 37, item 7)."""
