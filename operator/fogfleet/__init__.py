"""fogfleet: place robot-fleet software modules on robot, edge and cloud nodes; keep it right."""

__version__ = "0.1.0"
GROUP = "fogfleet.io"
VERSION = "v1alpha1"
API_VERSION = f"{GROUP}/{VERSION}"

__all__ = ["API_VERSION", "GROUP", "VERSION", "__version__"]
