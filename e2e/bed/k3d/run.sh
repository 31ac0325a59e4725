#!/usr/bin/env bash
# Run the fogfleet e2e suite on a k3d cluster (k3s in Docker) instead of the local control plane.
#
# Needs Docker and k3d (https://k3d.io) on PATH. NOT run on the fogfleet dev/CI machines, which
# have no Docker engine: this script is provided for users with Docker and has not been executed
# there. See e2e/README.md ("Running on k3d").
#
#   bash e2e/bed/k3d/run.sh [pytest args...]        # e.g. -k crd
#   FOGFLEET_K3D_KEEP=1 bash e2e/bed/k3d/run.sh     # keep the cluster afterwards
#
# Agents are labelled like e2e/bed/nodes.yaml (fogfleet.io/tier, fogfleet.io/robot,
# fogfleet.io/hardware-type); their names are k3d's (k3d-<cluster>-agent-N), not robot-1, so the
# tests select nodes by label. Tests that need the local harness (Prometheus file_sd, kwok node
# controls) skip themselves on an external cluster.
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)
cd "$ROOT"
# shellcheck disable=SC1091
source e2e/bed/versions.env

CLUSTER=${FOGFLEET_K3D_CLUSTER:-fogfleet-e2e}
IMAGE=${FOGFLEET_K3D_IMAGE:-$K3S_IMAGE}
API_PORT=${FOGFLEET_K3D_API_PORT:-16550}
STATE=${XDG_CACHE_HOME:-$HOME/.cache}/fogfleet/k3d
KUBECONFIG_OUT=$STATE/kubeconfig
PYTEST=${PYTEST:-$ROOT/.venv/bin/pytest}

for tool in docker k3d kubectl; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "e2e/bed/k3d/run.sh: '$tool' not found on PATH (this path needs Docker, k3d and kubectl)" >&2
    exit 2
  fi
done
docker info >/dev/null 2>&1 || { echo "e2e/bed/k3d/run.sh: the Docker engine is not reachable" >&2; exit 2; }

cleanup() {
  if [[ "${FOGFLEET_K3D_KEEP:-0}" != "1" ]]; then
    k3d cluster delete "$CLUSTER" >/dev/null 2>&1 || true
  else
    echo "kept k3d cluster $CLUSTER (kubeconfig: $KUBECONFIG_OUT); delete with: k3d cluster delete $CLUSTER"
  fi
}
trap cleanup EXIT

label() {  # label KEY=VALUE NODEFILTER -> a --k3s-node-label flag pair
  printf -- '--k3s-node-label\n%s@%s\n' "$1" "$2"
}
mapfile -t LABELS < <(
  # agent 0, 1: robots (robot-nuc); agent 2: big edge (dsv3-16); agent 3: small edge (fsv2-8);
  # server 0: cloud (fsv2-32)
  for i in 0 1; do
    label "fogfleet.io/tier=robot" "agent:$i"
    label "fogfleet.io/robot=robot-$((i + 1))" "agent:$i"
    label "fogfleet.io/hardware-type=robot-nuc" "agent:$i"
  done
  label "fogfleet.io/tier=edge" "agent:2"
  label "fogfleet.io/hardware-type=dsv3-16" "agent:2"
  label "fogfleet.io/tier=edge" "agent:3"
  label "fogfleet.io/hardware-type=fsv2-8" "agent:3"
  label "fogfleet.io/tier=cloud" "server:0"
  label "fogfleet.io/hardware-type=fsv2-32" "server:0"
)

mkdir -p "$STATE"
if ! k3d cluster list "$CLUSTER" >/dev/null 2>&1; then
  k3d cluster create "$CLUSTER" \
    --image "$IMAGE" \
    --servers 1 --agents 4 \
    --api-port "127.0.0.1:$API_PORT" \
    --no-lb \
    --k3s-arg "--disable=traefik@server:0" \
    --k3s-arg "--disable=servicelb@server:0" \
    --kubeconfig-update-default=false \
    --kubeconfig-switch-context=false \
    --wait --timeout 300s \
    "${LABELS[@]}"
fi
k3d kubeconfig get "$CLUSTER" >"$KUBECONFIG_OUT"
chmod 600 "$KUBECONFIG_OUT"
kubectl --kubeconfig "$KUBECONFIG_OUT" wait --for=condition=Ready nodes --all --timeout=180s
kubectl --kubeconfig "$KUBECONFIG_OUT" get nodes -L fogfleet.io/tier,fogfleet.io/hardware-type,fogfleet.io/robot

FOGFLEET_E2E_EXTERNAL=1 FOGFLEET_E2E_KUBECONFIG="$KUBECONFIG_OUT" FOGFLEET_E2E_KUBECTL="$(command -v kubectl)" \
  "$PYTEST" "$ROOT/e2e" --with-e2e -q "$@"
