"""The portable part of the e2e suite: what runs on any cluster whose nodes carry the labels
docs/development.md ("Running the e2e suite on your own cluster") names, through a plain
kubeconfig, with kubectl and helm and nothing of the local bed.

* ``settings``  what the run reads from the environment (binaries, image refs, pull policy)
* ``nodes``     which Nodes the suite may use, read from their labels, as ComputeNodes
* ``fleet``     a small ROS 2 fleet sized to those nodes (offloaded modules, an on-board fallback)
* ``chart``     the operator installed in-cluster by its Helm chart
* ``metrics``   a module pod's own counters, read through ``kubectl exec`` (no pod IP is dialled)

The tests are ``e2e/tests/test_portable.py``; the cluster is made by ``e2e/clusters`` for kind
and k3d, or is the user's own.
"""
