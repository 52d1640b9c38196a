"""lavapipe's rasterizer threads (LP_NUM_THREADS, read once when the Vulkan device starts, so
one value per process): ms per picture of each ManiSkill observation camera at 84x84, the
renderer before and the lean one (mimicgen_pipe/backends/maniskill/render.py), per thread
count.

    PYTHONPATH=$PWD .venv/bin/python lab/scripts/render_threads.py [--rounds 4] \
        [--frames 40] [--threads default 0 1 2] [--out lab/outputs/render_threads.json]

Each round starts one child process per thread count, in a rotated order, so that this
machine's drifting speed falls on all alike; each child renders the same states with both
renderers interleaved frame by frame and prints its medians. Prints, per thread count, the
median over rounds of each child's medians.
"""

from __future__ import annotations

if __name__ == "__main__":  # mimicgen-pipe's code paths, pinned before numpy or torch loads,
    from mimicgen_pipe.run import arithmetic  # as the stages pin them

    arithmetic.pin()

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

CAMERAS = ("agentview", "eye_in_hand")


def child(frames: int) -> None:
    sys.path.insert(0, str(Path(__file__).parent))
    from render_knobs import states

    from mimicgen_pipe.backends.maniskill.render import Renderer

    xs = states(frames)
    made = {
        "before": Renderer("stack_cube", "panda", 84, 84, CAMERAS, lean=False, shader="minimal"),
        "lean": Renderer("stack_cube", "panda", 84, 84, CAMERAS),
    }
    seconds: dict[str, dict[str, list[float]]] = {k: {c: [] for c in CAMERAS} for k in made}
    for r in made.values():
        r.images(xs[0])
    for i, state in enumerate(xs):
        for k in sorted(made, reverse=bool(i % 2)):
            r = made[k]
            r.seconds = dict.fromkeys(CAMERAS, 0.0)
            r.images(state)
            for c in CAMERAS:
                seconds[k][c].append(r.seconds[c])
    out = {k: {c: 1e3 * float(np.median(v)) for c, v in s.items()} for k, s in seconds.items()}
    print("RESULT " + json.dumps(out), flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=4)
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--threads", nargs="*", default=["default", "0", "1", "2"])
    p.add_argument("--out", default=None)
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child:
        child(args.frames)
        return
    runs: dict[str, list[dict]] = {t: [] for t in args.threads}
    for k in range(args.rounds):
        order = args.threads[k % len(args.threads) :] + args.threads[: k % len(args.threads)]
        for t in order:
            env = dict(os.environ)
            env.pop("LP_NUM_THREADS", None)
            if t != "default":
                env["LP_NUM_THREADS"] = t
            cmd = [sys.executable, __file__, "--child", "--frames", str(args.frames)]
            out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
            line = next(x for x in out.stdout.splitlines() if x.startswith("RESULT "))
            runs[t].append(json.loads(line.removeprefix("RESULT ")))
            print(t, line, flush=True)
    rows = []
    for t, rs in runs.items():
        row: dict[str, object] = {"LP_NUM_THREADS": t}
        for k in ("before", "lean"):
            for c in CAMERAS:
                row[f"ms_{k}_{c}"] = round(float(np.median([r[k][c] for r in rs])), 2)
        rows.append(row)
        print(json.dumps(row))
    if args.out:
        sys.path.insert(0, str(Path(__file__).parent))
        from render_knobs import machine

        result = {"rounds": args.rounds, "frames": args.frames, **machine(), "rows": rows}
        Path(args.out).write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
