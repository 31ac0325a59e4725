"""``python -m fogfleet.workload.dnn profile | models``: measure the split network's profile on
this machine (printed as the SoftwareModule's ``dnn`` field, to paste into a spec), or write its
ONNX models (the whole network, the local variant, every split's head and tail) from the seed,
as an image build would (``DNNSPLIT.md`` 3.3: "models generated at image-build time from a
seed ... committed as a generator script, not as weights")."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .network import NetSpec
from .store import write_models

CLOCKS = ("cpu", "wall")  # profile.CLOCKS' keys (profile needs onnxruntime and yaml)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fogfleet.workload.dnn", description=__doc__)
    sub = parser.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("profile", help="measure head/tail/full/local times and print YAML")
    m = sub.add_parser("models", help="write the ONNX models into a directory")
    m.add_argument("--out", type=Path, required=True, help="the directory (created if missing)")
    for s in (p, m):
        s.add_argument("--size", type=int, default=224, help="the frame's side (a multiple of 32)")
        s.add_argument("--width", type=float, default=1.0, help="the width multiplier")
        s.add_argument("--classes", type=int, default=1000)
        s.add_argument("--bottleneck", type=int, default=8, help="its channels (0: none)")
        s.add_argument("--seed", type=int, default=0, help="the weights' seed")
    p.add_argument("--runs", type=_whole, default=25, help="timed runs per part (median)")
    p.add_argument("--warmup", type=_whole_or_zero, default=5, help="untimed runs before them")
    p.add_argument(
        "--clock", choices=CLOCKS, default="cpu", help="the thread's CPU time or wall time"
    )
    ns = parser.parse_args(argv)
    try:
        spec = NetSpec(ns.size, ns.width, ns.classes, ns.bottleneck, ns.seed)
    except ValueError as exc:
        parser.error(str(exc))
    if ns.cmd == "profile":
        # here, not above: an image build writes the models with onnx alone
        from .profile import measure, to_yaml

        profile = measure(spec, ns.runs, ns.warmup, ns.clock)
        sys.stdout.write(to_yaml(profile, spec, ns.runs, ns.warmup, ns.clock))
        return 0
    return _write_models(spec, ns.out)


def _write_models(spec: NetSpec, out: Path) -> int:
    """The models a split module runs (``store.write_models``: every weight stored once)."""
    try:
        names = write_models(spec, out)
    except OSError as exc:
        print(f"fogfleet-dnn: cannot write the models to {out}: {exc}", file=sys.stderr)
        return 1
    print(f"fogfleet-dnn: wrote {spec.name} ({len(names)} splits) to {out}")
    return 0


def _whole(text: str, least: int = 1) -> int:
    """A whole number, at least ``least``."""
    try:
        value = int(text)
    except ValueError:
        value = least - 1
    if value < least:
        raise argparse.ArgumentTypeError(f"{text!r}: a whole number, at least {least}")
    return value


def _whole_or_zero(text: str) -> int:
    """A whole number, 0 or more."""
    return _whole(text, least=0)


if __name__ == "__main__":
    sys.exit(main())
