"""``make e2e-kind`` and ``make e2e-k3d``: a Docker-based cluster labelled as the portable suite
wants, the repository's images built with Docker and loaded into it, then the portable suite.

* ``layout``   the nodes (two robots, one edge) and the kind and k3d configurations that make them
* ``docker``   whether Docker can start the privileged containers kind and k3d need: a refusal
               names the reason before anything is created
* ``__main__`` ``python -m e2e.clusters kind|k3d``: check, create, load, test, delete

Neither runs on the fogfleet development machines (no Docker engine that can start privileged
containers); docs/development.md says so.
"""
