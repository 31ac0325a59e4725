"""What the other fleets claim, from the store, as one fleet plans (the room they hold is
``snapshot.room.held_by_others``: their claims and every pod's requests).

Planning is serialised (``Deps.planning``): a fleet plans into what the others claimed, and
records its own claims before the next one plans, so two fleets applied at the same moment
never plan the same room twice.
"""

from __future__ import annotations

from fogfleet.controllers.state import FleetKey, FleetStore
from fogfleet.snapshot.room import Claims

__all__ = ["claims_in"]


def claims_in(store: FleetStore) -> dict[FleetKey, Claims]:
    """Every fleet's claims, as recorded with its plan."""
    return {s.key: s.claims for s in store.states() if s.claims}
