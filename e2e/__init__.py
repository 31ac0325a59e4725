"""End-to-end: the local control-plane bed (``bed``), the tests on it (``tests``) and the
benchmarks on it (``bench``); see e2e/README.md."""
