"""What the operator and the ROS 2 workload image agree on, in the standard library only.

``metrics`` names the Prometheus metrics a module exports and builds the PromQL the operator
reads them with (CONTRACT.md); ``env`` names the ``FOGFLEET_*`` variables the operator renders
into a module's containers; ``quantity`` parses the Kubernetes quantities both sides read.
The workload image installs fogfleet without its dependencies, so nothing here may import a
third-party package or another fogfleet package (import-linter contract ``contract-stdlib``).
"""
