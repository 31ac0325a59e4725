"""The e2e tests: pytest e2e --with-e2e (make e2e) on the bed of e2e.bed, or on the cluster
FOGFLEET_E2E_KUBECONFIG names (make e2e KUBECONFIG=..., e2e/clusters): its portable part."""
