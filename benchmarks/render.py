"""Milliseconds per picture of each ManiSkill observation camera, before the lean scene and
after it (mimicgen_pipe/backends/maniskill/render.py), in one run, and the camera demos per
hour they give on 2 cores; written to metrics/benchmarks/render.json.

    python benchmarks/render.py [--episodes 2] [--steps 110] [--size 84] [--images docs/images]

States come from episodes of random arm motions (benchmarks/observe.py's, every step's
stored state), ``--steps`` steps each. "before" is the renderer as it was (``lean=False``,
SAPIEN's minimal shader, every triangle), "after" the observe stage's and the rendered
rollouts' (the lean scene, the Lambert shader pack), each for both cameras (as the observe
stage renders them) and for each camera alone. Every state is rendered by every setup in a
rotated order after one warm-up picture each, so that this machine's drifting speed (other
work shares its two cores) falls on all alike; a camera's ms per frame is the median over
the states of its picture plus its share of setting the scene (the stages' own count).
Camera demos per hour: demos of ``--steps`` steps with both cameras, on two workers that
each keep one core busy (observe.workers: 2), from one process's median ms per state.
``--images DIR``: the first state's pictures before and after, both cameras side by side,
upscaled 3x, as DIR/render_before.png and DIR/render_after.png.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from _machine import figures_path, machine
from observe import random_states

from mimicgen_pipe.backends.maniskill.render import Renderer

CAMERAS = ("agentview", "eye_in_hand")
CAMERA_SETS = (CAMERAS, ("agentview",), ("eye_in_hand",))
# setup -> the Renderer's keyword arguments
SETUPS = {"before": {"lean": False, "shader": "minimal"}, "after": {}}
WORKERS = 2  # observe.workers, one per core of the machines this is measured on
OUT = figures_path(__file__)


def save_pair(images: dict[str, dict[str, np.ndarray]], folder: Path) -> list[str]:
    """Each setup's pictures of one state, the cameras side by side, upscaled 3x (nearest)."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for setup, pictures in images.items():
        row = np.concatenate([pictures[c] for c in CAMERAS], axis=1)
        big = Image.fromarray(row).resize((row.shape[1] * 3, row.shape[0] * 3), Image.NEAREST)
        path = folder / f"render_{setup}.png"
        big.save(path)
        written.append(str(path))
    return written


def measure(states: np.ndarray, size: int) -> tuple[dict, dict]:
    """(setup/cameras -> per-state seconds of each camera and of the whole state, the first
    state's pictures of each setup's renderer of both cameras)."""
    made = {
        (setup, cameras): Renderer("stack_cube", "panda", size, size, cameras, **kwargs)
        for setup, kwargs in SETUPS.items()
        for cameras in CAMERA_SETS
    }
    first = {setup: made[setup, CAMERAS].images(states[0]) for setup in SETUPS}
    for r in made.values():
        r.images(states[0])  # first picture: buffers allocated, pipelines compiled
    keys = list(made)
    seconds = {k: {c: [] for c in (*k[1], "state")} for k in keys}
    for i, state in enumerate(states):
        for k in keys[i % len(keys) :] + keys[: i % len(keys)]:
            r = made[k]
            r.seconds = dict.fromkeys(r.cameras, 0.0)
            t0 = time.perf_counter()
            r.images(state)
            seconds[k]["state"].append(time.perf_counter() - t0)
            for c in r.cameras:
                seconds[k][c].append(r.seconds[c])
    for r in made.values():
        r.close()
    return seconds, first


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=2)
    p.add_argument("--steps", type=int, default=110, help="steps per episode (and per demo)")
    p.add_argument("--size", type=int, default=84, help="image height and width [px]")
    p.add_argument("--images", help="folder for the before/after pictures of the first state")
    p.add_argument("--out", default=str(OUT))
    args = p.parse_args()
    states = random_states("maniskill", "stack_cube", args.episodes, args.steps)
    seconds, first = measure(states, args.size)

    def ms(values: list[float]) -> float:
        return round(1e3 * float(np.median(values)), 2)

    rows = []
    for (setup, cameras), s in seconds.items():
        row = {"setup": setup, "cameras": "+".join(cameras), "ms_per_state": ms(s["state"])}
        rows.append(row | {f"ms_{c}": ms(s[c]) for c in cameras})
        print(json.dumps(rows[-1]))
    both = {setup: seconds[setup, CAMERAS] for setup in SETUPS}
    speedup = {
        f"{c}{'' if cameras == CAMERAS else '_alone'}": round(
            float(np.median(seconds["before", cameras][c]))
            / float(np.median(seconds["after", cameras][c])),
            2,
        )
        for cameras in CAMERA_SETS
        for c in cameras
    }
    demos_per_hour = {
        setup: round(WORKERS * 3600 / (args.steps * float(np.median(s["state"]))), 1)
        for setup, s in both.items()
    }
    result = {
        "task": "stack_cube",
        "size": args.size,
        "episodes": args.episodes,
        "steps_per_episode": args.steps,
        "states": len(states),
        **machine(),
        "timings": rows,
        "speedup_before_over_after": speedup,
        "camera_demos_per_hour_2_workers": demos_per_hour,
    }
    if args.images:
        result["images"] = save_pair(first, Path(args.images))
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps({"speedup": speedup, "demos_per_hour": demos_per_hour}), "->", args.out)


if __name__ == "__main__":
    main()
