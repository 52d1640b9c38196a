"""How far a policy's rollouts get, subtask by subtask: checkpoints rolled out as the
evaluate stage rolls them out (its scenes, blocks and workers, so a success rate is the
stage's), and for each subtask the episodes that ended it (its term signal's first rise
after the subtask before it ended, as parse finds subtask ends in a demo).

    python lab/scripts/rollouts_by_subtask.py --task drawer_cleanup --variant D0 \\
        --policy data/policies/drawer_cleanup_D0/seed0/epoch00200.pt [more .pt] \\
        [--episodes 50] [--component most_likely] [--horizon 600] \\
        [--backend maniskill] [--robot xarm6] [--out rollouts.json]
        [--cameras agentview eye_in_hand --image-size 64 64]   # an image policy

Prints, per checkpoint, one line per subtask (episodes that ended it, and of those that ended
the one before) and the success rate; ``--out`` writes the same and the step each episode
ended each subtask. ``--component`` and ``--horizon`` change the rollout protocol (the
mixture component acted on, mimicgen_pipe.learn.policy.COMPONENTS; the step limit, default the
task's) to measure what it does to the same checkpoints on the same scenes.
"""

from __future__ import annotations

if __name__ == "__main__":  # mimicgen-pipe's code paths, pinned before numpy or torch loads,
    from mimicgen_pipe.run import arithmetic  # so that a run here has the stages' last bits

    arithmetic.pin()

import argparse
import functools
import json
from pathlib import Path

from mimicgen_pipe import backends
from mimicgen_pipe.data.params import load_params
from mimicgen_pipe.learn.evaluation import EvalJob, Rollout, evaluate_policies, evaluation_seed
from mimicgen_pipe.learn.policy import COMPONENTS
from mimicgen_pipe.learn.training import load_rollout_policy
from mimicgen_pipe.run.executors import stage_executor
from mimicgen_pipe.stages import camera_renderer


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", required=True, nargs="+", help="checkpoints of the train stage")
    p.add_argument("--task", required=True)
    p.add_argument("--variant", default="D0")
    p.add_argument("--backend", default="maniskill")
    p.add_argument("--robot", default="panda", help="the arm the policy acts with")
    p.add_argument("--episodes", type=int, default=None, help="default: evaluate.episodes")
    p.add_argument("--params", default="params.yaml", help="for evaluate.seed and episodes")
    p.add_argument("--component", default="drawn", choices=COMPONENTS)
    p.add_argument("--horizon", type=int, default=None, help="default: the task's horizon")
    p.add_argument("--out", type=Path, help="a JSON file for the counts and every episode")
    p.add_argument("--cameras", nargs="+", default=(), help="an image policy's cameras")
    p.add_argument("--image-size", nargs=2, type=int, metavar=("H", "W"), default=None)
    args = p.parse_args()
    if args.out is not None and args.out.exists():  # before any work; nothing is replaced
        p.error(f"--out {args.out}: already exists; remove it or name another file")

    params = load_params(args.params)
    episodes = args.episodes or params.evaluate.episodes
    spec = backends.task_spec(args.backend, args.task)
    backends.check_robot(args.backend, args.robot)
    names = [s.name for s in spec.subtasks]
    job = EvalJob(
        make_env=functools.partial(
            backends.make_env, args.backend, args.task, args.robot, params.maniskill.lean_step
        ),
        load_policy=functools.partial(load_rollout_policy, component=args.component),
        variant=args.variant,
        horizon=args.horizon or spec.horizon,
        objects=spec.objects,
        term_signals=tuple(str(s.term_signal) for s in spec.subtasks[:-1]),
        make_cameras=camera_renderer(params, args.robot, tuple(args.cameras), args.image_size),
    )
    seeds = [evaluation_seed(params.evaluate.seed, args.variant, i) for i in range(episodes)]
    executor = stage_executor(params, "evaluate")
    label = f"rollouts {args.task} {args.variant}"
    rollouts = evaluate_policies(job, args.policy, seeds, executor, label)[0]
    out = [_by_subtask(path, rollouts[path], names) for path in args.policy]
    if args.out:
        protocol = {"component": args.component, "horizon": job.horizon}
        common = {"task": args.task, "variant": args.variant, "episodes": episodes} | protocol
        args.out.write_text(json.dumps(common | {"policies": out}, indent=2) + "\n")


def _by_subtask(path: str, rollouts: list[Rollout], names: list[str]) -> dict:
    """Print and return one checkpoint's episodes that ended each subtask."""
    episodes = len(rollouts)
    # the last subtask is reached when the task succeeds
    reached = [[*(e >= 0 for e in r.subtask_ends), r.success] for r in rollouts]
    counts = dict(zip(names, (sum(r[k] for r in reached) for k in range(len(names))), strict=True))
    print(f"\n{path}: {episodes} episodes")
    before = episodes
    for k, name in enumerate(names):
        both = sum(r[k] and (k == 0 or r[k - 1]) for r in reached)
        print(f"  {name:24s} reached {counts[name]:3d} ({both} of the {before} before)")
        before = counts[name]
    print(f"  success rate {100 * counts[names[-1]] / episodes:.1f} %")
    return {
        "policy": path,
        "reached": counts,
        "success_rate": 100 * counts[names[-1]] / episodes,
        "rollouts": [
            {
                "seed": r.seed,
                "success": r.success,
                "steps": r.steps,
                "subtask_ends": list(r.subtask_ends),
            }
            for r in rollouts
        ],
    }


if __name__ == "__main__":
    main()
