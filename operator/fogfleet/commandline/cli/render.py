"""``fogfleet render`` and ``fogfleet crds``: the Kubernetes objects of a fleet's plan, offline
(a folder's fleets planned as one site, as ``fogfleet plan`` plans them), and the CRDs
generated from the models."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from fogfleet.commandline.exits import BAD_INPUT, FAILED, OK

from .common import catalog_of, degradation, refusal, site_plans

__all__ = ["cmd_crds", "cmd_render"]


def cmd_render(args: argparse.Namespace) -> int:
    import yaml

    from fogfleet.domain.fallback import fleet_fallbacks
    from fogfleet.render.deployments import (
        LABEL_FLEET,
        LABEL_MANAGED_BY,
        MANAGER,
        label_value,
        render_fleet,
    )
    from fogfleet.render.ros import (
        RosWiring,
        discovery_servers,
        fleet_network_policies,
        service_address,
    )

    catalog = catalog_of(args.paths)
    docs: list[dict[str, Any]] = []
    _, plans = site_plans(catalog, args, args.scheduler)
    for site in plans:
        fleet, problem, schedule, settings = (
            site.snapshot.fleet,
            site.problem,
            site.schedule,
            site.settings,
        )
        if not schedule.feasible and not args.allow_unplaced:
            print(
                f"fogfleet render: RobotFleet {problem.namespace}/{problem.fleet} cannot run as "
                f"planned ({refusal(site)}); nothing rendered. --allow-unplaced renders what fits.",
                file=sys.stderr,
            )
            return BAD_INPUT
        if schedule.degraded:  # rendered all the same: say so where a pipe does not hide it
            print(
                f"DEGRADED {problem.namespace}/{problem.fleet}: {degradation(site)}",
                file=sys.stderr,
            )
        ns = problem.namespace
        modules = {name: m for (mns, name), m in catalog.modules.items() if mns == ns}
        wiring = None
        if fleet.spec.ros.enabled:
            labels = {LABEL_FLEET: label_value(problem.fleet), LABEL_MANAGED_BY: MANAGER}
            servers = discovery_servers(problem, fleet.spec.ros, labels, [])
            # offline: the Services' DNS names (the operator uses their cluster IPs)
            wiring = RosWiring(fleet.spec.ros, {r: service_address(s) for r, s, _ in servers})
            for _, service, deployment in servers:
                docs += [service, deployment]
            ports = sorted({p for m in modules.values() for p in m.spec.template.metrics_ports()})
            docs += fleet_network_policies(
                fleet=problem.fleet,
                namespace=ns,
                selector={LABEL_FLEET: label_value(problem.fleet)},
                robots=sorted({inst.robot for inst in problem.instances}),
                metrics_ports=ports,
                owner_refs=[],
            )
        deployments = render_fleet(
            problem,
            modules,
            schedule.placement,
            baseline=schedule.scheduler == "k8s-default",
            with_limits=schedule.with_limits,
            cpu_limit_percent=fleet.spec.scheduler.cpu_limit_percent,
            fallbacks=fleet_fallbacks(fleet.spec, modules),
            plan_id=f"cli-{schedule.scheduler}-{settings.seed}",
            wiring=wiring,
        )
        docs.extend(deployments)
        docs.extend(_hpas(deployments, modules, ns, problem.fleet))

    class _NoAliases(yaml.SafeDumper):
        def ignore_aliases(self, data: Any) -> bool:
            return True

    print(yaml.dump_all(docs, Dumper=_NoAliases, sort_keys=False), end="")
    return 0


def _hpas(
    deployments: list[dict[str, Any]], modules: Any, namespace: str, fleet: str
) -> list[dict[str, Any]]:
    """The HPAs of the shared modules with ``backend: hpa``, said on stderr. The Deployment an
    HPA scales leaves ``spec.replicas`` to it (else every re-apply would reset its count)."""
    from fogfleet.render.scaling import module_hpas

    by_name = {d["metadata"]["name"]: d for d in deployments}
    out = []
    for item in module_hpas(deployments, modules, namespace, fleet):
        by_name[item.target]["spec"].pop("replicas", None)
        spec = item.hpa["spec"]
        metric = spec["metrics"][0]
        what = (
            f"External metric {metric['external']['metric']['name']}, which a metrics adapter "
            "must serve"
            if metric["type"] == "External"
            else "CPU utilisation (metrics-server)"
        )
        print(
            f"fogfleet render: SoftwareModule {namespace}/{item.module} has scaling.backend hpa: "
            f"HorizontalPodAutoscaler {item.hpa['metadata']['name']} scales Deployment "
            f"{item.target} between {spec['minReplicas']} and {spec['maxReplicas']} replicas on "
            f"{what}; its {item.fixed} other planned replica(s) stay where planned. The "
            "operator does not apply it: apply it with these objects.",
            file=sys.stderr,
        )
        out.append(item.hpa)
    return out


def cmd_crds(args: argparse.Namespace) -> int:
    from fogfleet.artefacts import files

    if args.check:
        drift = files.check_crds(Path(args.check))
        for line in drift:
            print(line, file=sys.stderr)
        if drift:
            print(
                "CRDs drifted from the models: run `make crds` and commit the result.",
                file=sys.stderr,
            )
            return FAILED
        print(f"{args.check}: CRDs match the models")
        return OK
    for path in files.write_crds(Path(args.out)):
        print(path)
    return 0
