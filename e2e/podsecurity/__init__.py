"""Pod Security Standards checks on rendered pods (issue 37, item 8)."""
