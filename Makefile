# fogfleet — run `make help` for the targets.
SHELL := /bin/bash
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
export PYTHONDONTWRITEBYTECODE := 1
CACHE_HOME := $(or $(XDG_CACHE_HOME),$(HOME)/.cache)/fogfleet
# checkov lives in its own venv outside the repo (its dependencies would fight ours).
CHECKOV_VERSION ?= 3.3.30
CHECKOV_VENV ?= $(CACHE_HOME)/checkov-$(CHECKOV_VERSION)
CHECKOV := BC_SKIP_MAPPING=TRUE CHECKOV_RUN_SCA_PACKAGE_SCAN_V2=false $(CHECKOV_VENV)/bin/checkov --framework kubernetes --skip-download --quiet --compact

.DEFAULT_GOAL := help

help: ## Show this help
	@awk 'BEGIN {FS = ":.*##"} /^[a-zA-Z0-9_-]+:.*##/ {printf "  \033[36m%-16s\033[0m %s\n", $$1, $$2}' $(MAKEFILE_LIST)

$(BIN)/fogfleet: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q -U pip
	$(BIN)/pip install --progress-bar off -e '.[dev,ros]'  # not -q: a cold install is a minute of downloads, and make demo never goes silent for 30 s
	@touch $@

venv: $(BIN)/fogfleet ## Create .venv with fogfleet and the dev tools

lint: venv ## ruff, mypy (strict on the pure core) and import-linter contracts
	$(BIN)/ruff check operator tests e2e
	$(BIN)/mypy
	$(BIN)/lint-imports

unit: venv ## Unit tests: the fast tier, each under 1 s (no cluster, no processes; tests/integration/conftest.py)
	FOGFLEET_STRICT_UNIT=1 $(BIN)/pytest tests/unit -q -m "not integration" --durations=10

integration: venv ## Integration tests: rclpy workload processes, the operator under KopfRunner on a fake API, tests over 1 s
	$(BIN)/pytest tests -q -m integration

test-stress: venv ## The unit and integration tiers 5 times in random order while a burner keeps every core busy (~35 min; not part of make test): run it before you stop whenever you touch tests
	$(BIN)/python tests/stress/run.py --runs $(or $(RUNS),5)

test: venv lint crds-check docs-check cluster-tools unit integration chart-lint checkov dashboard-check images ## Everything CI runs: lint, CRD drift, docs check, unit and integration tests, chart lint, checkov, e2e on the local bed (real and kwok nodes); stops the bed after (KEEP_BED=1 keeps it)
	@status=0; $(MAKE) --no-print-directory e2e || status=$$?; \
	if [ "$(KEEP_BED)" = 1 ]; then echo "KEEP_BED=1: the bed keeps running (make cluster-down stops it)"; \
	else $(BIN)/python e2e/bed/harness.py down || status=1; fi; \
	exit $$status

crds: venv ## Write the CRD YAML in crds/ and the chart's generated files (CRD templates, Grafana dashboard, alert rules)
	$(BIN)/fogfleet crds --out crds

crds-check: venv ## Fail when crds/ or the chart's generated files drift from the models and artefacts/dashboard.py
	$(BIN)/fogfleet crds --check crds

docs-check: venv ## Fail when README.md or docs/ name a missing file, anchor, make target or CLI flag
	$(BIN)/pytest tests/docs -q

cluster-tools: venv ## Build (or reuse from ~/.cache/fogfleet) etcd, kube-*, kwok, helm, kube-router, Prometheus and CoreDNS
	$(BIN)/python e2e/bed/harness.py build

cloud-tools: venv ## Build (or reuse from ~/.cache/fogfleet) Open Cluster Management's hub and agent for the cloud cluster (make cluster-up CLOUD=1, the multicluster tests)
	$(BIN)/python e2e/bed/harness.py build --only ocm

images: venv ## Build (or reuse from ~/.cache/fogfleet/images) the operator, workload, pause and busybox images without Docker
	$(BIN)/python e2e/bed/images.py build

bed-builds: venv ## cluster-tools and images side by side (the Go compiles use the CPU, the images mostly the network and disk); their progress lines interleave
	$(MAKE) --no-print-directory -j2 cluster-tools images

cluster-up: venv ## Start the local bed (control plane, Prometheus, cluster DNS, kwok and real nodes) on 127.0.0.1 and the bed bridge; PROFILE=paper for the paper's real nodes, PROFILE=kwok for kwok nodes only; CLOUD=1 adds a cloud cluster joined by Open Cluster Management
	$(BIN)/python e2e/bed/harness.py up --profile $(or $(PROFILE),default) $(if $(filter 1,$(CLOUD)),--cloud)

cluster-down: venv ## Stop the local control plane and remove its state
	$(BIN)/python e2e/bed/harness.py down

cluster-status: venv ## Show the local control plane's processes and health
	$(BIN)/python e2e/bed/harness.py status

# The tools and images are built (or found in ~/.cache/fogfleet) before pytest starts: a fresh
# machine's first build takes many minutes, more than any test's timeout.
# `make e2e KUBECONFIG=<file>` (on make's command line; the shell's KUBECONFIG is ignored) runs
# the portable part on that cluster instead, with kubectl and helm from FOGFLEET_E2E_KUBECTL /
# FOGFLEET_E2E_HELM, else the bed's (when built), else PATH; tests needing the bed are deselected.
E2E_KUBECONFIG := $(if $(filter command line,$(origin KUBECONFIG)),$(abspath $(KUBECONFIG)))
E2E_PORTABLE_ENV := FOGFLEET_E2E_EXTERNAL=1 FOGFLEET_E2E_KUBECONFIG=$(E2E_KUBECONFIG)
e2e: venv $(if $(E2E_KUBECONFIG),,cluster-tools cloud-tools images) ## End-to-end tests on the local bed (started if not running; a demo left on it is removed first), each test named as it runs; KUBECONFIG=<file>: the portable part on that cluster
	$(if $(E2E_KUBECONFIG),$(E2E_PORTABLE_ENV) $(BIN)/pytest e2e/tests -v --durations=10 --with-e2e,$(BIN)/python e2e/demo.py remove && $(BIN)/pytest e2e -v --durations=25 --with-e2e -m "not long")

test-long: venv cluster-tools images ## The long scenarios make test leaves out for CI's time (marker long: benchmark runs, slow faults, the slowed link; ~35 min); the paper-bed run restarts the bed last
	$(BIN)/python e2e/demo.py remove
	$(BIN)/pytest e2e -v --durations=25 --with-e2e -m long

test-faults: venv cluster-tools images ## The fault suite alone (issue 37), with the long faults make test leaves out (node reboots, control-plane restart, discovery, long cut, leader; ~25 min); records faults.json and regenerates the table of docs/survives.md
	rm -f faults.json
	$(BIN)/python e2e/demo.py remove
	FOGFLEET_FAULTS_RECORD=$(CURDIR)/faults.json $(BIN)/pytest e2e -v --durations=25 --with-e2e -m faults
	$(BIN)/python -m e2e.faults.report --json faults.json --docs docs/survives.md

e2e-kind: venv ## A kind cluster (Docker) labelled for the portable suite, images loaded, the suite run; refuses where Docker cannot run privileged containers
	$(BIN)/python -m e2e.clusters kind

e2e-k3d: venv ## The same on k3d (Docker); refuses where Docker cannot run privileged containers
	$(BIN)/python -m e2e.clusters k3d

chart-lint: venv ## helm lint + helm template of charts/fogfleet (helm from the cluster tools)
	$(BIN)/python e2e/bed/harness.py helm lint --strict charts/fogfleet
	$(BIN)/python e2e/bed/harness.py helm template fogfleet charts/fogfleet -n fogfleet-system > /dev/null

# Grafana's dashboard schema types, in their own venv outside the repo (like checkov).
GRAFANA_SDK_VERSION ?= 1769699998!10.1.0
GRAFANA_SDK_VENV ?= $(CACHE_HOME)/grafana-sdk-10.1.0

$(GRAFANA_SDK_VENV)/bin/python:
	$(PY) -m venv $(GRAFANA_SDK_VENV)
	$(GRAFANA_SDK_VENV)/bin/pip install -q 'grafana-foundation-sdk==$(GRAFANA_SDK_VERSION)'

dashboard-check: $(GRAFANA_SDK_VENV)/bin/python ## The chart's Grafana dashboard read back through Grafana's schema types (grafana-foundation-sdk): nothing unknown, nothing changed
	$(GRAFANA_SDK_VENV)/bin/python tests/dashboard/check_dashboard.py charts/fogfleet/dashboards/fogfleet.json

$(CHECKOV_VENV)/bin/checkov:
	$(PY) -m venv $(CHECKOV_VENV)
	$(CHECKOV_VENV)/bin/pip install -q checkov==$(CHECKOV_VERSION)

checkov: venv $(CHECKOV_VENV)/bin/checkov ## checkov (offline) over manifests/install, manifests/ocm-hub, the rendered chart and the rendered warehouse and split-network Deployments
	@d=$$(mktemp -d); trap 'rm -rf "$$d"' EXIT; set -e; \
	$(BIN)/python e2e/bed/harness.py helm template fogfleet charts/fogfleet -n fogfleet-system > "$$d/chart.yaml"; \
	mkdir "$$d/rendered"; $(BIN)/fogfleet render manifests/examples/warehouse > "$$d/rendered/warehouse.yaml"; \
	$(BIN)/fogfleet render manifests/examples/split-network > "$$d/rendered/split-network.yaml"; \
	for target in manifests/install manifests/ocm-hub "$$d/chart.yaml"; do \
	  echo "checkov: $$target"; \
	  if [ -d "$$target" ]; then $(CHECKOV) -d "$$target"; else $(CHECKOV) -f "$$target"; fi; \
	done; \
	echo "checkov: fogfleet render manifests/examples/warehouse and split-network (the user's images: digest and pull policy are theirs)"; \
	$(CHECKOV) -d "$$d/rendered" --skip-check CKV_K8S_43,CKV_K8S_15

bench: venv ## Benchmarks of the pure core: scheduling (misses, MILP gap, decision time) and autoscaling (tinyKube); prints tables, writes bench-*.json and docs/benchmarks/core.md
	$(BIN)/fogfleet bench scheduling --record bench-scheduling.json
	$(BIN)/fogfleet bench autoscaling --runs 7 --record bench-autoscaling.json
	$(BIN)/fogfleet bench page --records bench-scheduling.json,bench-autoscaling.json --out docs/benchmarks/core.md

bench-replan: venv ## A robot joining and an edge failing at 100, 300 and 1000 robots: whole-fleet vs incremental re-plan (seconds, moves, miss rate; ~10 min)
	$(BIN)/fogfleet bench replan --robots $(or $(SIZES),100,300,1000) --runs 3

bench-scale-plan: venv ## The first whole-fleet plan of 1000 robots (8000 instances, 1400 nodes), with and without the robot bound's priced plan, gaps to the LP bound and the robot bound on seeds 1-5, peak memory; writes bench-scale-plan.json (~25 min)
	$(BIN)/fogfleet bench scale-plan --robots $(or $(SIZES),1000) --runs 3 --record bench-scale-plan.json

bench-plan-budget: venv ## The first plan of 1000 robots at timeBudgetMillis 5, 8, 12 and 20 s, and on a tenth of the edges (short of CPU, degraded) at 8 and 20 s (3 runs each): the planner's seconds against the budget, the stages it cut, the gap to the robot bound, the instances degraded; writes bench-plan-budget.json (~10 min)
	$(BIN)/fogfleet bench budget --robots $(or $(SIZES),1000) --runs 3 --record bench-plan-budget.json

bench-plan-page: venv ## docs/benchmarks/planning.md from bench-scale-plan.json, bench-plan-budget.json and bench-why-live.json
	$(BIN)/fogfleet bench page --title "Planning a large fleet" --records bench-scale-plan.json,bench-plan-budget.json,bench-why-live.json --out docs/benchmarks/planning.md

bench-scale-page: venv ## docs/benchmarks/scale.md from bench-scale.json (make bench-scale's record)
	$(BIN)/fogfleet bench page --title "A large fleet on the cluster" --records bench-scale.json --out docs/benchmarks/scale.md

bench-why: venv ## How long `kubectl fogfleet why` computes at 1000 robots (build, refusals, explanation; median of 5)
	$(BIN)/fogfleet bench why --robots $(or $(SIZES),1000) --runs 5

bench-why-live: venv cluster-tools ## `kubectl fogfleet why` on a contended 1000-robot fleet on a bed of kwok nodes only (PROFILE=kwok), API reads included (median of 5; BASELINE=DIR compares an operator/ directory of another checkout); writes the record bench-why-live.json (~35 min with its teardown)
	$(BIN)/python -m e2e.bench.why_live --runs 5 $(if $(BASELINE),--baseline $(BASELINE)) --record bench-why-live.json

bench-cluster: venv ## Operator benchmarks on the local control plane: apply-to-Running latency (40 and 400 pods), nsga2 vs kube-scheduler's real placement (~25 min)
	$(BIN)/python -m e2e.bench.cluster --runs 5

bench-scale: venv cluster-tools ## The operator at 100, 300 and 1000 robots x 8 modules on kwok nodes: apply-to-Running vs plain, Ready lag, peak RSS, a robot joining; writes bench-scale.json
	$(BIN)/python -m e2e.bench.scale --sizes $(or $(SIZES),100,300,1000) --repeats $(or $(REPEATS),1)

bench-real: venv cluster-tools images ## The paper's real experiment on the paper bed (started if not running): nsga2, nsga2-static, kube-scheduler (k8s-default) and kube-scheduler with honest requests (k8s-requests) x6 each + on-board x1, 90 s warm-up + 60 s windows; writes bench-real.json (~80 min); RESUME=FILE finishes a stopped run's schedule
	$(BIN)/python -m e2e.bench.real $(if $(RESUME),--resume $(RESUME))

bench-split: venv cluster-tools images ## A split network vs the whole network on the edge and on the robot, on the default bed's real nodes at a fast and a slow link (3 blocks x 3 arms, 20 s settle + 30 s windows; ~20 min); writes bench-split.json and docs/benchmarks/split.md
	$(BIN)/python -m e2e.bench.split --docs docs/benchmarks/split.md

bench-real-report: venv ## Tables, docs/benchmarks/real-nodes.md and its plot from bench-real.json, with the simulator judged under the declared and the fitted model
	$(BIN)/python -m e2e.bench.real.report --json bench-real.json --docs docs/benchmarks/real-nodes.md --plot docs/benchmarks/real-nodes-perception.svg --model docs/benchmarks/real-nodes-model.json

bench-real-pilot: venv cluster-tools images ## The simulator's pilot on the paper bed: nsga2 x2, k8s-default x2, k8s-requests x1 (~25 min); writes bench-real-pilot.json for bench-real-fit
	$(BIN)/python -m e2e.bench.real --arms nsga2=2,k8s-default=2,k8s-requests=1 --json bench-real-pilot.json

PILOT ?= docs/benchmarks/real-nodes-pilot.json
bench-real-fit: venv ## The simulator's execution model (the cycle's cost, the kernel's spreading) fitted on the pilot alone (PILOT=file): docs/benchmarks/real-nodes-model.json
	$(BIN)/python -m e2e.bench.real.fit --pilot $(PILOT) --out docs/benchmarks/real-nodes-model.json

demo: venv bed-builds ## Plan + simulate the warehouse fleet, then leave it running on the local bed with the operator installed in-cluster by Helm; prints what to type next
	$(BIN)/fogfleet plan manifests/examples/warehouse
	$(BIN)/fogfleet simulate manifests/examples/warehouse --scheduler all --all-active
	$(BIN)/python e2e/demo.py

kubectl: venv ## kubectl on the local bed: make kubectl ARGS="get robotfleets -A"
	@$(BIN)/python e2e/bed/harness.py kubectl $(ARGS)

demo-offline: venv ## Only plan + simulate the warehouse fleet (no cluster, a few seconds)
	$(BIN)/fogfleet plan manifests/examples/warehouse
	$(BIN)/fogfleet simulate manifests/examples/warehouse --scheduler all --all-active

clean: ## Remove the virtualenv and caches in the repo
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache


.PHONY: cloud-tools bed-builds test-faults dashboard-check kubectl help venv lint unit integration docs-check test checkov images crds crds-check demo-offline bench-replan bench-scale-plan bench-plan-budget bench-plan-page bench-scale-page bench-why-live bench-cluster bench-scale bench-real bench-real-report bench-real-pilot bench-real-fit bench-split cluster-tools cluster-up cluster-down cluster-status e2e e2e-kind e2e-k3d chart-lint bench demo clean
