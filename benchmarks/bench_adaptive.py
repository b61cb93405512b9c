"""Adaptive motion vs the fixed ``fast`` protocol: robot motion time to 0.3 mm / 0.05 deg std (issue 16; run by hand).

    python benchmarks/bench_adaptive.py --robots panda sawyer ur5e --seeds 0

A thin script over :mod:`skincal.bench.adaptive`: per robot and seed, 6 units (paper
placement), ``realistic`` IMUs and ``controller`` joint states, the streaming calibrator fed by the
adaptive loop and by the whole ``fast`` protocol; prints the motion times and the true (worst-unit)
errors, optionally JSON.
"""

from __future__ import annotations

import dataclasses
import json

from rich.console import Console
from rich.table import Table

from skincal.bench import options
from skincal.bench.adaptive import run_case
from skincal.bench.harness import parse_args
from skincal.bench.script import run_script
from skincal.workflows.live import parse_target


def _f(x: float | None, fmt: str = ".1f") -> str:
    return "-" if x is None else format(x, fmt)


def main() -> None:
    args = parse_args(__doc__.splitlines()[0], options.ADAPTIVE)
    target = parse_target(args.target)
    console = Console(width=200)
    rows = []
    for robot in args.robots:
        for seed in args.seeds:
            rows.append(run_case(robot, seed, args.noise, target, args.max_motion, std_factor=args.std_factor))
            console.print(f"{robot} seed {seed} done", highlight=False)
    title = f"motion time to {target.text()} std, 6 units, {args.noise} IMUs, controller joint states"
    if args.std_factor != 1.0:
        title += f" (the adaptive loop to {args.std_factor:g} x that std)"
    table = Table(title=title)
    for col in ("robot", "seed", "adaptive [s]", "segments", "reached", "true err [mm / deg]", "links",
                "true err in target at [s]", "fast [s]", "fast std at target [s]", "fast err there",
                "fast true err in target at [s]", "fast err at end"):  # fmt: skip
        table.add_column(col)
    for r in rows:
        table.add_row(
            r.robot, str(r.seed), f"{r.adaptive_s:.1f}", str(r.adaptive_segments),
            "yes" if r.adaptive_reached else "NO",
            f"{r.adaptive_pos_mm:.3f} / {r.adaptive_rot_deg:.4f}", "ok" if r.adaptive_links_ok else "WRONG",
            _f(r.adaptive_true_s), f"{r.fixed_s:.1f}", _f(r.fixed_reached_s),
            "-" if r.fixed_reached_pos_mm is None else f"{r.fixed_reached_pos_mm:.3f} / {r.fixed_reached_rot_deg:.4f}",
            _f(r.fixed_true_s),
            f"{r.fixed_end_pos_mm:.3f} / {r.fixed_end_rot_deg:.4f}",
        )  # fmt: skip
    console.print(table)
    if args.json is not None:
        args.json.write_text(json.dumps([dataclasses.asdict(r) for r in rows], indent=2))


if __name__ == "__main__":
    raise SystemExit(run_script(main))
