"""One view of the cluster for every entry point (issue 45): the listed objects (as the API
server or a folder gives them) into a typed ``FleetSnapshot``, and one ``problem_of(snapshot,
what_if=None)``. The operator, the ``fogfleet`` commands and ``kubectl fogfleet`` plan through
it; a folder of several fleets is one site (``plan_site``).

Pure: it imports no Kubernetes, kopf or Prometheus client code.

    objects.py   readers of raw objects (Node health, bound nodes, the modules' status)
    catalog.py   listed objects -> the planning catalog (capacity, health, room held)
    room.py      room held by other tenants, and the note that names them in cores
    snapshot.py  FleetSnapshot, from listed objects or a folder's catalog
    problem.py   problem_of and its steps (build), what-ifs, refusals
    site.py      several fleets planned as one site, in numbered steps
    live.py      a fleet with its deployed placement (Live), and why each instance runs there
"""

from .objects import fleet_key
from .problem import (
    Built,
    WhatIf,
    build,
    built_problem,
    problem_of,
    refused,
    unavailable_in,
    with_what_if,
)
from .room import held_by_others, room_note
from .site import SitePlan, plan_site
from .snapshot import FleetSnapshot, Listed, snapshot_of, snapshot_of_catalog

__all__ = [
    "Built",
    "FleetSnapshot",
    "Listed",
    "SitePlan",
    "WhatIf",
    "build",
    "built_problem",
    "fleet_key",
    "held_by_others",
    "plan_site",
    "problem_of",
    "refused",
    "room_note",
    "snapshot_of",
    "snapshot_of_catalog",
    "unavailable_in",
    "with_what_if",
]
