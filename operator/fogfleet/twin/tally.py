"""What a simulated service's requests met, counted as ``make bench``'s autoscaling suite
counts it (:mod:`fogfleet.bench.autoscaling`, tinyKube V): rejections per privacy class and
SLO violations among the answered requests. Pure.

A test reads two tallies of a running twin and compares their difference
(:meth:`Tally.since`) with the benchmark's figures.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

from .model import Rejected, Served

__all__ = ["Tally"]


@dataclass(frozen=True)
class Tally:
    private_arrived: int = 0
    private_rejected: int = 0
    normal_arrived: int = 0
    normal_rejected: int = 0
    served: int = 0
    late: int = 0  # answered after the request's own target

    def add(self, records: Iterable[Served | Rejected]) -> Tally:
        """This tally with ``records`` counted. A request counts as arrived when it is
        rejected or answered, so requests still queued at a read are left for the next."""
        t = self
        for rec in records:
            rejected = isinstance(rec, Rejected)
            if rec.private:
                t = replace(t, private_arrived=t.private_arrived + 1,
                            private_rejected=t.private_rejected + rejected)  # fmt: skip
            else:
                t = replace(t, normal_arrived=t.normal_arrived + 1,
                            normal_rejected=t.normal_rejected + rejected)  # fmt: skip
            if isinstance(rec, Served):
                t = replace(t, served=t.served + 1, late=t.late + rec.late)
        return t

    def since(self, earlier: Tally) -> Tally:
        """What was counted after ``earlier`` (a read of the same service)."""
        return Tally(*(getattr(self, f) - getattr(earlier, f) for f in self.__dataclass_fields__))

    def figures(self) -> dict[str, float]:
        """The benchmark's metrics: ``privacyRejected``, ``normalRejected`` (fractions of each
        class) and ``sloViolations`` (fraction of answered requests past their own target)."""

        def share(part: int, whole: int) -> float:
            return part / whole if whole else 0.0

        return {
            "privacyRejected": share(self.private_rejected, self.private_arrived),
            "normalRejected": share(self.normal_rejected, self.normal_arrived),
            "sloViolations": share(self.late, self.served),
        }
