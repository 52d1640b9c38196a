"""What a two-arm task's constraints buy: the DGR of a task's fixed attempts with its spec as
written and with its constraints removed (each arm then selects its own source demo for
every subtask and starts each subtask as soon as its own previous one ends), on the same
parsed source demos, attempt seeds and action noise.

    python lab/scripts/two_arm_constraints.py --task two_robot_lift_bar --variants D0 D1 \\
        --attempts 200 --out lab/outputs/two_arm_constraints_two_robot_lift_bar.json

Prints a line per (variant, spec) and writes the figures to ``--out``.
"""

from __future__ import annotations

if __name__ == "__main__":  # mimicgen-pipe's code paths, pinned before numpy or torch loads,
    from mimicgen_pipe.run import arithmetic  # so that a run here has the stages' last bits

    arithmetic.pin()

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from mimicgen_pipe import backends  # noqa: E402
from mimicgen_pipe.data import layout  # noqa: E402
from mimicgen_pipe.data.store import read_store  # noqa: E402
from mimicgen_pipe.method.generation import GenerationConfig, run_attempt  # noqa: E402
from mimicgen_pipe.run.runner import attempt_seed, source_demos  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="two_robot_lift_bar")
    p.add_argument("--variants", nargs="+", default=["D0", "D1"])
    p.add_argument("--attempts", type=int, default=200)
    p.add_argument("--action-noise", type=float, default=0.025)
    p.add_argument("--parsed", help="parsed store (default: data/parsed/<task>.zarr)")
    p.add_argument("--out", required=True, help="figures JSON")
    args = p.parse_args()

    spec = backends.task_spec("maniskill", args.task)
    if not spec.constraints:
        sys.exit(f"task {args.task} has no constraints to remove")
    parsed = Path(args.parsed or layout.parsed_store(args.task))
    store = read_store(parsed, task=args.task, kind="parsed")
    sources = source_demos(store, spec.objects, spec.arms)
    config = GenerationConfig(action_noise=args.action_noise)
    specs = {"as written": spec, "no constraints": dataclasses.replace(spec, constraints=())}
    env = backends.make_env("maniskill", args.task)
    rows = []
    try:
        for variant in args.variants:
            for name, s in specs.items():
                t0, kept, failures = time.perf_counter(), 0, {}
                for i in range(args.attempts):
                    a = run_attempt(env, sources, s, config, variant, attempt_seed(0, variant, i))
                    kept += a.success
                    if not a.success:
                        sub = s.subtasks[a.failed_subtask]
                        failures[f"{sub.arm} {sub.name}"] = (
                            failures.get(f"{sub.arm} {sub.name}", 0) + 1
                        )
                row = {
                    "variant": variant,
                    "spec": name,
                    "attempts": args.attempts,
                    "successes": kept,
                    "dgr": 100.0 * kept / args.attempts,
                    "failures": failures,
                    "seconds": time.perf_counter() - t0,
                }
                rows.append(row)
                print(f"{args.task} {variant} {name}: DGR {row['dgr']:.1f}% "
                      f"({kept}/{args.attempts}), failures {failures}")  # fmt: skip
    finally:
        env.close()
    out = {
        "task": args.task,
        "constraints": [dataclasses.asdict(c) for c in spec.constraints],
        "action_noise": args.action_noise,
        "parsed": str(parsed),
        "rows": rows,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    print(f"-> {args.out}")


if __name__ == "__main__":
    main()
