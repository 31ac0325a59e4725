"""The e2e tests: pytest e2e --with-e2e (make e2e) on the bed of e2e.bed, or on the cluster
FOGFLEET_E2E_KUBECONFIG names (e2e/bed/k3d/run.sh)."""
