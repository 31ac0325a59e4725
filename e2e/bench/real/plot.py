"""The per-run figure of the real-nodes comparison as a hand-written SVG (pure; deterministic).

It also holds the few accessors of a bench-real.json run that ``report`` shares with it ("did
this run complete", "its rate on an endpoint", the arms in ``protocol.ARMS`` order):
``report`` imports this module for its CLI, so they live here, one layer down.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Mapping, Sequence
from typing import Any
from xml.sax.saxutils import escape

from e2e.bench.real.protocol import ARMS, PRIMARY

__all__ = ["arm_order", "completed", "plot_svg", "rate"]

Run = Mapping[str, Any]

COLOURS = {
    "nsga2": "#1f77b4",
    "nsga2-static": "#17becf",
    "k8s-default": "#d62728",
    "k8s-requests": "#ff7f0e",
    "onboard": "#7f7f7f",
}
OTHER_COLOUR = "#9467bd"

# symlog axis: y ~ log10(1 + rate / LINEAR_PCT) with the rate in percent; linear below
# LINEAR_PCT, logarithmic above, and 0 is a real point on it
LINEAR_PCT = 0.1
TICKS_PCT = (0.0, 0.1, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0)
WIDTH, HEIGHT = 640, 430
LEFT, RIGHT, TOP, BOTTOM = 80, 620, 56, 330  # the plot area; BOTTOM is the rate 0
FAILED_Y = 352  # the strip under the axis where failed runs sit


def completed(run: Run) -> bool:
    """A run enters the statistics only if it did not fail and has its measurements."""
    return not run.get("failed") and isinstance(run.get("measured"), Mapping)


def rate(run: Run, endpoint: str = PRIMARY, kind: str = "measured") -> float | None:
    """The run's ``kind`` (measured/simulated) miss rate on ``endpoint`` ("perception",
    "allModules" or a module), or None if it has none (failed, or no finite figure)."""
    block = run.get(kind)
    if run.get("failed") or not isinstance(block, Mapping):
        return None
    value = block.get(endpoint)
    if value is None and endpoint in (block.get("modules") or {}):
        value = block["modules"][endpoint]
    if isinstance(value, Mapping):
        value = value.get("missRate")
    if not isinstance(value, int | float) or math.isnan(value) or math.isinf(value):
        return None
    return float(value)


def arm_order(runs: Iterable[Run]) -> list[str]:
    """The arms the runs name: the known ones in ``ARMS`` order, any other after, sorted."""
    named = {str(r["scheduler"]) for r in runs}
    return [a for a in ARMS if a in named] + sorted(named - set(ARMS))


def _num(x: float) -> str:
    return f"{x:.1f}"


def _top_pct(values_pct: Sequence[float]) -> float:
    """The axis top: the smallest tick at or above every rate (at least 1 %)."""
    need = max([1.0, *values_pct])
    return next((t for t in TICKS_PCT if t >= need), math.ceil(need))


def _y(rate_pct: float, top_pct: float) -> float:
    f = math.log10(1 + rate_pct / LINEAR_PCT) / math.log10(1 + top_pct / LINEAR_PCT)
    return BOTTOM - f * (BOTTOM - TOP)


def _axis(top_pct: float) -> list[str]:
    out = [
        f'<line class="axis" x1="{LEFT}" y1="{TOP}" x2="{LEFT}" y2="{BOTTOM}" stroke="#000"/>',
        f'<line class="axis" x1="{LEFT}" y1="{BOTTOM}" x2="{RIGHT}" y2="{BOTTOM}" stroke="#000"/>',
    ]
    for t in (t for t in TICKS_PCT if t <= top_pct):
        y = _num(_y(t, top_pct))
        label = "0" if t == 0 else f"{t:g} %"
        out += [
            f'<line class="grid" x1="{LEFT}" y1="{y}" x2="{RIGHT}" y2="{y}" stroke="#ddd"/>',
            f'<line class="tick" x1="{LEFT - 5}" y1="{y}" x2="{LEFT}" y2="{y}" stroke="#000"/>',
            f'<text x="{LEFT - 8}" y="{y}" text-anchor="end" dominant-baseline="middle">'
            f"{label}</text>",
        ]
    out.append(
        f'<text x="{LEFT - 8}" y="{FAILED_Y}" text-anchor="end" dominant-baseline="middle" '
        'font-style="italic">failed</text>'
    )
    mid = (TOP + BOTTOM) / 2
    out.append(
        f'<text x="18" y="{_num(mid)}" text-anchor="middle" '
        f'transform="rotate(-90 18 {_num(mid)})">miss rate (symlog)</text>'
    )
    return out


def _marker(x: float, y: float, colour: str, tip: str, failed: bool) -> str:
    paint = f'fill="none" stroke="{colour}"' if failed else f'fill="{colour}"'
    cls = "run failed" if failed else "run"
    return (
        f'<circle class="{cls}" cx="{_num(x)}" cy="{_num(y)}" r="4" {paint}>'
        f"<title>{escape(tip)}</title></circle>"
    )


def _column(
    arm: str,
    indexed: Sequence[tuple[int, Run]],
    centre: float,
    half: float,
    top_pct: float,
    ep: str,
) -> list[str]:
    """One arm: a marker per run (jittered by its index in the document), the median bar."""
    colour = COLOURS.get(arm, OTHER_COLOUR)
    rates = [(i, run, rate(run, ep)) for i, run in indexed]
    values = [100 * r for _, _, r in rates if r is not None]
    out: list[str] = []
    if values:  # the bar first: the dots stay visible on it
        bar = _num(_y(statistics.median(values), top_pct))
        out.append(
            f'<line class="median" x1="{_num(centre - half * 0.6)}" y1="{bar}" '
            f'x2="{_num(centre + half * 0.6)}" y2="{bar}" stroke="{colour}" stroke-width="3"/>'
        )
    for i, run, r in rates:
        jitter = ((i * 0.6180339887) % 1.0 - 0.5) * half  # golden-ratio steps: spread, fixed
        shown = f"failed: {run.get('failed')}" if r is None else f"{100 * r:.2f} %"
        y = FAILED_Y if r is None else _y(100 * r, top_pct)
        tip = f"{arm} seed {run.get('seed')}: {shown}"
        out.append(_marker(centre + jitter, y, colour, tip, failed=r is None))
    label = f"{arm} (n={len(values)})"
    out.append(f'<text x="{_num(centre)}" y="{BOTTOM + 48}" text-anchor="middle">{label}</text>')
    return out


def plot_svg(doc: Mapping[str, Any]) -> str:
    """Each run's primary-endpoint miss rate by arm: a column per arm (``ARMS`` order), a dot
    per completed run, a bar at the arm's median, failed runs hollow in a strip under the axis.

    The axis is symlog, y ~ log10(1 + rate / 0.1 %): onboard's 30-60 % and the planners'
    0-5 % differ by two orders of magnitude, so a linear axis flattens the planners into its
    floor, while a log axis cannot show the 0.0 rates a good run has. The symlog is linear
    near 0 (0 is a real point, labelled "0") and logarithmic above 0.1 %, with no break.
    """
    runs = list(doc.get("runs") or [])
    ep = str(doc.get("primaryEndpoint", PRIMARY))
    arms = arm_order(runs)
    rates = [100 * r for r in (rate(x, ep) for x in runs) if r is not None]
    top_pct = _top_pct(rates)
    bed = doc.get("bed") or {}
    title = (
        f"{ep[:1].upper()}{ep[1:]} miss rate per run on the real nodes, {doc.get('date', '?')}, "
        f"scale factor F = {bed.get('scale', '?')}"
    )
    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{HEIGHT}" '
        f'viewBox="0 0 {WIDTH} {HEIGHT}" font-family="sans-serif" font-size="12">',
        f'<rect width="{WIDTH}" height="{HEIGHT}" fill="#fff"/>',
        f'<text class="title" x="{WIDTH / 2:g}" y="24" text-anchor="middle" font-size="14">'
        f"{escape(title)}</text>",
        *_axis(top_pct),
    ]
    step = (RIGHT - LEFT) / max(len(arms), 1)
    for k, arm in enumerate(arms):
        indexed = [(i, r) for i, r in enumerate(runs) if r["scheduler"] == arm]
        out += _column(arm, indexed, LEFT + step * (k + 0.5), step / 2, top_pct, ep)
    legend = (
        "dot: a completed run; bar: the arm's median; hollow: a failed run (no rate)",
        f"axis: linear below {LINEAR_PCT:g} %, logarithmic above (symlog)",
    )
    for k, line in enumerate(legend):
        out.append(
            f'<text class="legend" x="{WIDTH / 2:g}" y="{HEIGHT - 26 + 15 * k}" '
            f'text-anchor="middle" font-size="11" fill="#444">{escape(line)}</text>'
        )
    return "\n".join([*out, "</svg>", ""])
