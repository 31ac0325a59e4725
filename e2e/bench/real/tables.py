"""How the real-node benchmark's pages write a rate and a table (pure): one form for the
report (``report``) and the simulator's section (``modelpage``)."""

from __future__ import annotations

import math

__all__ = ["md_table", "pct", "text_table"]

Rows = list[list[str]]


def pct(x: float | None) -> str:
    """A rate in percent with two decimals; "-" where there is none (None or NaN)."""
    return "-" if x is None or math.isnan(x) else f"{100 * x:.2f} %"


def text_table(header: list[str], rows: Rows) -> str:
    """Columns padded to their widest cell, for a terminal."""
    widths = [max(len(r[k]) for r in [header, *rows]) for k in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in rows]
    head = "  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)).rstrip()
    return "\n".join([head, "-" * len(head), *lines])


def md_table(header: list[str], rows: Rows) -> str:
    """A Markdown table (a "|" in a cell escaped)."""

    def line(cells: list[str]) -> str:
        return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"

    return "\n".join([line(header), "|" + "---|" * len(header), *map(line, rows)])
