"""Where a peg_insertion policy's rollouts end: the peg head in the hole's frame, as
ManiSkill's success test measures it, at the end of each episode.

    python lab/scripts/peg_insertion_rollouts.py \\
        --policy data/policies/peg_insertion_D0_cpu3/seed1/epoch00100.pt [--episodes 20] \\
        [--variant D0] [--component most_likely] [--out rollouts.json]

Rolls the checkpoint out on the evaluate stage's first scenes of the variant (one process),
up to the task's horizon, and prints per episode: success, the step it ended, whether the
peg is still grasped, the head's depth x along the hole's axis [m] and its distance from the
axis [m] at the end, the deepest x reached, and how far x moved over the last 50 steps [m].
The box's face is at x = -(the peg's half-length), -0.085 m; success needs x >= -0.015 (7 cm
in). A summary sorts the failures: stopped grasped at the hole's mouth (within 2 cm in front
of the face and 1 cm of the axis), held at the face further off the axis, in the hole short
of success, other.
"""

from __future__ import annotations

if __name__ == "__main__":  # mimicgen-pipe's code paths, pinned before numpy or torch loads,
    from mimicgen_pipe.run import arithmetic  # so that a run here has the stages' last bits

    arithmetic.pin()

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np
from _followed import Followed

from mimicgen_pipe import backends
from mimicgen_pipe.backends.maniskill import peg_in_hole
from mimicgen_pipe.data.params import load_params
from mimicgen_pipe.learn.evaluation import evaluation_seed, rollout
from mimicgen_pipe.learn.policy import COMPONENTS
from mimicgen_pipe.learn.training import load_rollout_policy
from mimicgen_pipe.method.generation import Env

TASK = "peg_insertion"


def head_in_hole(env: Env) -> tuple[float, float]:
    """The peg head's depth along the hole's axis and its distance from the axis [m]."""
    x, y, z = peg_in_hole.head_in_hole(env.unwrapped)
    return float(x), float(np.hypot(y, z))


def failure_kind(row: dict, face: float, radius: float) -> str:
    """Where a failed episode ended (face: the box's face along the hole's axis, radius: the
    hole's [m])."""
    if not row["grasped"]:
        return "dropped the peg"
    if row["depth_m"] > face + 0.002 and row["off_axis_m"] < radius:
        return "in the hole, short of success"
    if face - 0.02 < row["depth_m"] <= face + 0.002:
        aligned = row["off_axis_m"] < 0.01
        return "stopped at the mouth" if aligned else "held at the face, off the axis"
    return "other"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", required=True, help="a checkpoint of the train stage (.pt)")
    p.add_argument("--variant", default="D0")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--component", default="drawn", choices=COMPONENTS)
    p.add_argument("--out", type=Path, help="a JSON file with every episode")
    args = p.parse_args()
    if args.out is not None and args.out.exists():  # before any work; nothing is replaced
        p.error(f"--out {args.out}: already exists; remove it or name another file")
    spec = backends.task_spec("maniskill", TASK)
    backends.check_variant(spec, args.variant)
    policy = load_rollout_policy(args.policy, args.component)
    env = backends.make_env("maniskill", TASK)
    face = -float(env.unwrapped.peg_half_sizes[0, 0])
    radius = float(env.unwrapped.box_hole_radii[0])
    seed0 = load_params().evaluate.seed
    rows = []
    for i in range(args.episodes):
        seed = evaluation_seed(seed0, args.variant, i)
        heads: list[tuple[float, float]] = []  # after the reset, then after every step
        followed = Followed(env, lambda e, heads=heads: heads.append(head_in_hole(e)))
        r = rollout(followed, policy, seed, args.variant, spec.horizon, spec.objects)
        depth = [x for x, _ in heads[1:]]
        off_axis = heads[-1][1]
        rows.append(
            {
                "seed": seed,
                "success": r.success,
                "steps": r.steps,
                "grasped": bool(env.subtask_signals()["grasp_peg"]),
                "depth_m": round(depth[-1], 4),
                "off_axis_m": round(off_axis, 4),
                "deepest_m": round(max(depth), 4),
                "moved_last_50_m": round(float(np.abs(np.diff(depth[-50:])).sum()), 4),
            }
        )
        print(rows[-1], flush=True)
    env.close()
    kinds = Counter(failure_kind(r, face, radius) for r in rows if not r["success"])
    wins = len(rows) - sum(kinds.values())
    print(f"{wins} of {len(rows)} inserted; failures: {dict(kinds)} (the face at x = {face:.4f})")
    if args.out is not None:
        args.out.write_text(json.dumps({"policy": args.policy, "episodes": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
