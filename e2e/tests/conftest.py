"""Fixtures for end-to-end tests against a real Kubernetes API server.

By default the tests run on the local control plane of e2e/bed/harness.py (started on
demand, left running). With ``FOGFLEET_E2E_EXTERNAL=1 FOGFLEET_E2E_KUBECONFIG=<path>`` they run
against that one explicit cluster instead (``make e2e KUBECONFIG=<path>``, ``make e2e-kind``,
``make e2e-k3d``): only the tests marked ``portable`` run there; every other e2e test says in
one line, ``pytest.mark.bed("<what of the bed it needs>")``, why it cannot, and is deselected
(the summary prints each reason with its count). An e2e test with neither marker is an error.

Fixtures (generic, for the smoke tests and the operator suites that come later):

* ``cluster``   session; the harness's :class:`Cluster` (local mode only, else the test skips)
* ``kube``      session; :class:`Kube`: guarded kubeconfig path, ``kubectl()``, ``apply()``,
                ``api_client()``
* ``namespace`` per test; a fresh namespace (its ``default`` ServiceAccount exists), deleted after
* ``diagnostics`` per test; a list to append ``() -> (title, text)`` callables to, dumped with
                the namespace objects, events and component logs when the test fails

The guard refuses any kubeconfig that is not the harness's own (server
``https://127.0.0.1:<its port>``) or, in external mode, the one explicitly named.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from e2e.bed import cloud, harness, ocm, realnodes
from e2e.bed.kube import Kube, UnsafeKubeconfig, guard_kubeconfig
from e2e.bed.operator_fixtures import Operator, install_crds
from e2e.tests import cloudbed

if TYPE_CHECKING:
    from e2e.tests.scaling_rig import Rig

ENV_EXTERNAL = "FOGFLEET_E2E_EXTERNAL"
ENV_KUBECONFIG = "FOGFLEET_E2E_KUBECONFIG"
ENV_KUBECTL = "FOGFLEET_E2E_KUBECTL"
ENV_KEEP_NAMESPACES = "FOGFLEET_E2E_KEEP_NAMESPACES"

Diagnostic = Callable[[], tuple[str, str]]


def pytest_addoption(parser: pytest.Parser) -> None:
    with contextlib.suppress(ValueError):  # already added by a conftest higher up
        parser.addoption(
            "--with-e2e",
            action="store_true",
            default=False,
            help="run tests marked e2e (starts the local control plane unless "
            f"{ENV_EXTERNAL}=1 names another cluster)",
        )


_DESELECTED = pytest.StashKey[dict[str, int]]()


def _bed_reason(item: pytest.Item) -> str | None:
    """Why an e2e test cannot run on another cluster (its ``bed`` marker), None if portable."""
    if item.get_closest_marker("portable") is not None:
        return None
    marker = item.get_closest_marker("bed")
    if marker is None or len(marker.args) != 1 or not str(marker.args[0]).strip():
        raise pytest.UsageError(
            f'{item.nodeid}: an e2e test is marked portable or bed("<what of the bed it needs>")'
        )
    return str(marker.args[0])


def _keep_portable(config: pytest.Config, items: list[pytest.Item]) -> None:
    """On another cluster: deselect (never skip) every e2e test that needs the bed."""
    kept, dropped, reasons = [], [], {}
    for item in items:
        reason = _bed_reason(item) if item.get_closest_marker("e2e") is not None else None
        if reason is None:
            kept.append(item)
        else:
            dropped.append(item)
            reasons[reason] = reasons.get(reason, 0) + 1
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        items[:] = kept
    config.stash[_DESELECTED] = reasons


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption("--with-e2e"):
        if _external():
            _keep_portable(config, items)
        # a test on the paper bed restarts the bed with the paper profile: it runs last, so
        # every other test has the suite's bed (the order is otherwise kept)
        items.sort(key=lambda item: item.get_closest_marker("paperbed") is not None)
        return
    skip = pytest.mark.skip(
        reason="e2e test: needs a Kubernetes control plane; run `make e2e` (pytest e2e --with-e2e)"
    )
    for item in items:
        if item.get_closest_marker("e2e") is not None:
            item.add_marker(skip)


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: pytest.Config) -> None:
    """Never skip silently: name every e2e test that did not run here, and why (on an
    external cluster such as k3d, the tests that need the local bed's powers: kwok node
    controls, emulated links, the harness's Prometheus)."""
    if not config.getoption("--with-e2e"):
        return
    deselected = config.stash.get(_DESELECTED, {})
    if deselected:
        total = sum(deselected.values())
        terminalreporter.section(f"e2e tests deselected: they need the local bed ({total})")
        for reason, count in sorted(deselected.items()):
            terminalreporter.line(f"{count:4d}  {reason}")
    skipped = terminalreporter.stats.get("skipped", [])
    if not skipped:
        return
    terminalreporter.section(f"e2e tests not run on this cluster ({len(skipped)})")
    for report in skipped:
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        terminalreporter.line(f"{report.nodeid}: {reason.removeprefix('Skipped: ')}")


_SESSION_KUBE: Kube | None = None


def _external() -> bool:
    return os.environ.get(ENV_EXTERNAL, "") not in ("", "0", "false", "no")


def _kubectl_bin() -> str:
    for candidate in (os.environ.get(ENV_KUBECTL), str(harness.BIN_DIR / "kubectl")):
        if candidate and Path(candidate).exists():
            return candidate
    found = shutil.which("kubectl")
    if found is None:
        raise pytest.UsageError(f"no kubectl: set {ENV_KUBECTL} or put kubectl on PATH")
    return found


def _connect(request: pytest.FixtureRequest) -> Kube:
    explicit = os.environ.get(ENV_KUBECONFIG)
    cluster: harness.Cluster | None = None
    if _external():
        if not explicit:
            raise UnsafeKubeconfig(f"{ENV_EXTERNAL}=1 needs {ENV_KUBECONFIG}=<path>")
        path = Path(explicit).expanduser().resolve()
        server = guard_kubeconfig(path, expected_server=None)
    else:
        if explicit:
            raise UnsafeKubeconfig(
                f"{ENV_KUBECONFIG} is set but {ENV_EXTERNAL} is not; set {ENV_EXTERNAL}=1 to "
                "run against that cluster, or unset it to use the local control plane"
            )
        capture = request.config.pluginmanager.getplugin("capturemanager")
        with capture.global_and_fixture_disabled():  # show build/start progress live
            cluster = harness.ensure_up()
        path = cluster.kubeconfig
        server = guard_kubeconfig(path, expected_server=cluster.api_server)
    return Kube(
        kubeconfig=path,
        server=server,
        kubectl_bin=_kubectl_bin(),
        external=_external(),
        cluster=cluster,
    )


@pytest.fixture(scope="session")
def _e2e_target(request: pytest.FixtureRequest) -> Iterator[tuple[Kube, harness.Cluster | None]]:
    global _SESSION_KUBE
    try:
        kube = _connect(request)
    except UnsafeKubeconfig as exc:  # stop the whole session, not one error per test
        pytest.exit(f"fogfleet e2e guard: {exc}", returncode=pytest.ExitCode.USAGE_ERROR)
    except harness.HarnessError as exc:
        pytest.exit(
            f"fogfleet e2e: the local control plane is not available:\n{exc}",
            returncode=pytest.ExitCode.TESTS_FAILED,
        )
    path = kube.kubeconfig
    saved = os.environ.get("KUBECONFIG")
    os.environ["KUBECONFIG"] = str(path)  # libraries that default to $KUBECONFIG see ours only
    _SESSION_KUBE = kube
    try:
        yield kube, kube.cluster
    finally:
        _SESSION_KUBE = None
        if saved is None:
            os.environ.pop("KUBECONFIG", None)
        else:
            os.environ["KUBECONFIG"] = saved


@pytest.fixture(scope="session")
def kube(_e2e_target: tuple[Kube, harness.Cluster | None]) -> Kube:
    return _e2e_target[0]


@pytest.fixture(scope="session")
def cluster(_e2e_target: tuple[Kube, harness.Cluster | None]) -> harness.Cluster:
    """The local control plane (Prometheus, kwok node controls). On another cluster a test
    that asks for it is mislabelled (a portable test must not need it): it errors."""
    if _e2e_target[1] is None:
        pytest.fail("needs the local bed, which another cluster is not: mark the test "
                    'bed("<why>") so it is deselected there', pytrace=False)  # fmt: skip
    return _e2e_target[1]


def _namespace_name(nodeid: str) -> str:
    base = re.sub(r"[^a-z0-9]+", "-", nodeid.split("::")[-1].lower()).strip("-")
    return f"e2e-{base[:44].strip('-')}-{secrets.token_hex(3)}"


@pytest.fixture
def namespace(kube: Kube, request: pytest.FixtureRequest) -> Iterator[str]:
    """A fresh namespace whose `default` ServiceAccount exists; deleted after the test."""
    name = _namespace_name(request.node.nodeid)
    kube.create_namespace(name, {"fogfleet.io/e2e": "true"})
    yield name
    if os.environ.get(ENV_KEEP_NAMESPACES):
        return
    kube.kubectl("delete", "namespace", name, "--wait=false", "--ignore-not-found", check=False)


@pytest.fixture(scope="module")
def crds(kube: Kube) -> None:
    """fogfleet's CRDs, applied from crds/ and Established."""
    install_crds(kube)


@pytest.fixture
def operator(
    kube: Kube, crds: None, namespace: str, tmp_path: Path, diagnostics: list[Diagnostic]
) -> Iterator[Operator]:
    """``fogfleet run`` as a local process serving the test's namespace; its log is dumped
    when the test fails. A suite that needs another operator defines its own."""
    op = Operator(kube.kubeconfig, [namespace], tmp_path / "operator.log")
    diagnostics.append(lambda: ("operator log", op.logs(150)))
    op.start().wait_live()
    yield op
    # delete the fleets while the operator still runs, so their finalizers are removed
    kube.kubectl("delete", "robotfleets", "--all", "-n", namespace, "--wait=true",
                 "--timeout=60s", check=False, timeout=90)  # fmt: skip
    op.stop()


@pytest.fixture(scope="module")
def joined(
    cluster: harness.Cluster, request: pytest.FixtureRequest
) -> Iterator[tuple[cloud.CloudCluster, ocm.Joined]]:
    """The cloud cluster joined to the bed by OCM (``cloudbed.joined_cloud``), for one test
    module: each multicluster module joins it afresh and stops it after. A module that sets
    ``CLOUD_REAL_NODE = True`` gets the cloud's real node too (``cloud.start_node``)."""
    real_node = bool(getattr(request.module, "CLOUD_REAL_NODE", False))
    with cloudbed.joined_cloud(cluster, real_node=real_node) as both:
        yield both


@pytest.fixture
def site_operator(
    joined: tuple[cloud.CloudCluster, ocm.Joined],
    kube: Kube,
    crds: None,
    namespace: str,
    tmp_path: Path,
    diagnostics: list[Diagnostic],
) -> Iterator[Operator]:
    """``fogfleet run`` at the site with the hub's kubeconfig (across the WAN) and the site's
    Zenoh router, and none of the cloud cluster's credentials (``cloudbed.site_operator``)."""
    with cloudbed.site_operator(joined[0], kube, namespace, tmp_path, diagnostics) as op:
        yield op


@pytest.fixture
def diagnostics() -> list[Diagnostic]:
    """Append `() -> (title, text)` callables; they are dumped when the test fails."""
    return []


@pytest.fixture
def rig(
    kube: Kube, cluster: harness.Cluster, crds: None, namespace: str, diagnostics: list[Diagnostic]
) -> Iterator[Rig]:
    """The SLO scaler's rig in the test's namespace (``scaling_rig``; the autoscaling tests)."""
    from e2e.tests.scaling_rig import scaling_rig  # the scaler's imports, only where used

    with scaling_rig(kube, cluster, namespace, diagnostics) as r:
        yield r


# --------------------------------------------------------------------------------------------
# failure dump


def _limit(text: str, lines: int) -> str:
    rows = text.rstrip().splitlines()
    if len(rows) <= lines:
        return "\n".join(rows)
    return "\n".join([*rows[:lines], f"... ({len(rows) - lines} more lines)"])


def _dump(kube: Kube, namespace: str | None, extra: list[Diagnostic]) -> str:
    out: list[str] = []

    def section(title: str, text: str) -> None:
        out.append(f"===== {title} =====\n{text.rstrip()}\n")

    def run(*args: str) -> str:
        try:
            proc = kube.kubectl(*args, check=False, timeout=30)
        except (subprocess.TimeoutExpired, OSError) as exc:
            return f"({exc})"
        return proc.stdout + proc.stderr

    if namespace:
        section(
            f"events in {namespace}",
            run("get", "events", "-n", namespace, "--sort-by=.lastTimestamp", "-o", "wide"),
        )
        # the fleets' conditions first: the yaml below is cut long before a fleet's status
        conditions = (
            '{range .items[*]}{.metadata.name}{"\\n"}{range .status.conditions[*]}'
            '{"  "}{.type}={.status} {.reason} ({.lastTransitionTime}): {.message}{"\\n"}'
            "{end}{end}"
        )
        section(
            f"fleets' conditions in {namespace}",
            run("get", "robotfleets", "-n", namespace, "-o", f"jsonpath={conditions}"),
        )
        kinds = run("api-resources", "--verbs=list", "--namespaced", "-o", "name").split()
        skip = {"events", "events.events.k8s.io"}
        kinds = [k for k in kinds if k not in skip]
        if kinds:
            section(
                f"objects in {namespace}",
                _limit(run("get", ",".join(kinds), "-n", namespace, "-o", "wide"), 100),
            )
            section(
                f"objects in {namespace} (yaml)",
                _limit(run("get", ",".join(kinds), "-n", namespace, "-o", "yaml"), 400),
            )
    section("nodes", run("get", "nodes", "-o", "wide", "--show-labels=false"))
    section(
        "warning events (all namespaces)",
        _limit(
            run("get", "events", "-A", "--field-selector=type=Warning", "--sort-by=.lastTimestamp"),
            40,
        ),
    )
    for fn in extra:
        try:
            title, text = fn()
        except Exception as exc:  # a broken diagnostic must not hide the failure
            title, text = getattr(fn, "__name__", "diagnostic"), f"(failed: {exc!r})"
        section(title, text)
    if kube.cluster is not None:
        for component in harness.COMPONENTS:
            section(
                f"log tail: {component} ({kube.cluster.logs_dir}/{component}.log)",
                kube.cluster.log_tail(component, 25),
            )
        for node in kube.cluster.real_nodes:
            section(f"real node {node}", _limit(realnodes.diagnose(realnodes.declared(node)), 120))
    return "\n".join(out)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    outcome = yield
    report: pytest.TestReport = outcome.get_result()  # type: ignore[attr-defined]
    if not report.failed or report.when not in ("setup", "call"):
        return
    if item.get_closest_marker("e2e") is None or _SESSION_KUBE is None:
        return
    funcargs = getattr(item, "funcargs", {})
    ns = funcargs.get("namespace")
    extra = funcargs.get("diagnostics") or []
    report.sections.append(
        (
            "fogfleet e2e diagnostics",
            _dump(_SESSION_KUBE, ns if isinstance(ns, str) else None, list(extra)),
        )
    )
