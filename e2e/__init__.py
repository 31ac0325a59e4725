"""End-to-end tests and the local control-plane harness (see e2e/README.md)."""
