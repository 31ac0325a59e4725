"""The ROS 2 workload: one rclpy program that plays any SoftwareModule from its spec.

The operator renders every module instance with ``FOGFLEET_*`` environment variables (who it
is, where it runs, the CPU it was given, its spec); ``python -m fogfleet.workload module`` then
subscribes and publishes the module's topics at their sizes and rates, burns the CPU its
profile says for that CPU (multi-robot-edge-cloud-scheduling Fig. 3), honours the activation
rate (Table II) and exports the metrics contract (``fogfleet.contract.metrics``) measured
from its real cycles. ``discovery-server`` runs the robot's Fast DDS discovery server.

Only ``module`` needs rclpy; spec parsing, the CPU model and the message header are plain
Python and unit-tested without ROS.
"""
