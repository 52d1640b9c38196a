"""Where a ManiSkill camera picture's time goes: one knob of the scene or renderer changed at a
time, each against the baseline, interleaved frame by frame in one process.

    PYTHONPATH=$PWD .venv/bin/python lab/scripts/render_knobs.py [--frames 60] \
        [--knobs baseline no_ground ...] [--out lab/outputs/render_knobs.json]

Each knob gets its own Renderer (mimicgen_pipe/backends/maniskill/render.py, both observation
cameras, 84x84) with the knob applied to its scene: the baseline is the renderer before the
lean scene (lean=False, SAPIEN's minimal shader); knobs named lean+ start from the lean one.
Every frame, every renderer renders the same stored state in a rotated order, so that this
machine's drifting speed (another job shares its two cores) falls on all alike. Per knob and
camera: the median ms of take_picture + get_picture("Color"), the median ms of the state
set + update_render, and the ratio baseline / knob of those medians. Prints one JSON line per knob.
"""

from __future__ import annotations

if __name__ == "__main__":  # mimicgen-pipe's code paths, pinned before numpy or torch loads,
    from mimicgen_pipe.run import arithmetic  # as the stages pin them

    arithmetic.pin()

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from mimicgen_pipe.backends.maniskill import render
from mimicgen_pipe.backends.maniskill.render import Renderer

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from _machine import machine  # the benchmarks' own, from the folder put on the path above
from observe import random_states

CAMERAS = ("agentview", "eye_in_hand")
ARM_PREFIX = "panda_"
SIZE = ("width", "height")


def states(n: int) -> np.ndarray:
    """n stored states of one episode of random arm motions (benchmarks/observe.py's)."""
    return random_states("maniskill", "stack_cube", 1, n)


def _sub_scene(r: Renderer):
    return r._env.unwrapped.scene.sub_scenes[0]


def _bodies(r: Renderer, keep: Callable[[str], bool]):
    import sapien

    for entity in _sub_scene(r).entities:
        body = entity.find_component_by_type(sapien.render.RenderBodyComponent)
        if body is not None and keep(entity.name):
            yield entity, body


def remove_bodies(r: Renderer, keep: Callable[[str], bool]) -> None:
    for entity, body in list(_bodies(r, keep)):
        entity.remove_component(body)


def invisible(r: Renderer, keep: Callable[[str], bool]) -> None:
    for _, body in _bodies(r, keep):
        body.visibility = 0.0


def remove_lights(r: Renderer) -> None:
    """Ambient light only: the two directional lights ManiSkill's tables add removed."""
    for light in list(_sub_scene(r).render_system.lights):
        light.entity.remove_component(light)


def ground_quad(r: Renderer) -> None:
    """The ground grid as the quad it spans (render.flat_quad), alone."""
    for entity, _ in list(_bodies(r, is_ground)):
        render._replace_meshes(entity, render.flat_quad)


def arm_cells(r: Renderer, links: float, wrist: float) -> None:
    """The arm's links clustered at ``links`` m, its wrist link at ``wrist`` m, alone (as
    render.lean_scene does them)."""
    for link in r._env.unwrapped.agent.robot.links:
        cell = wrist if link.name == "panda_hand" else links
        for obj in link._objs:
            render._replace_meshes(obj.entity, lambda *m, c=cell: render._clustered(*m[:3], c))


def is_arm(name: str) -> bool:
    return name.startswith(ARM_PREFIX)


def is_ground(name: str) -> bool:
    return name.endswith("ground")


def is_table(name: str) -> bool:
    return name.endswith("table-workspace")


def is_cube(name: str) -> bool:
    return "cube" in name


Apply = Callable[[Renderer], None]
BEFORE = {"lean": False, "shader": "minimal"}
LEAN: dict = {}  # the renderer's defaults for observation cameras
CELLS = (render.LINK_CELL, render.WRIST_CELL)

# knob -> (Renderer keyword arguments, what is done to its scene after it is made); the
# baseline is the renderer before (BEFORE); knobs named lean+ start from the lean renderer
KNOBS: dict[str, tuple[dict, tuple[Apply, ...]]] = {
    "baseline": (BEFORE, ()),
    "baseline_again": (BEFORE, ()),  # the noise floor: the same as the baseline
    "size_32": (BEFORE | {"width": 32, "height": 32}, ()),
    "size_16": (BEFORE | {"width": 16, "height": 16}, ()),
    "shader_trivial": (BEFORE | {"shader": "trivial"}, ()),
    "shader_lambert": (BEFORE | {"shader": render.LEAN_SHADER}, ()),
    "no_lights": (BEFORE, (remove_lights,)),
    "no_ground": (BEFORE, (lambda r: remove_bodies(r, is_ground),)),
    "ground_visibility_0": (BEFORE, (lambda r: invisible(r, is_ground),)),
    "ground_quad": (BEFORE, (ground_quad,)),
    "no_table": (BEFORE, (lambda r: remove_bodies(r, is_table),)),
    "arm_cluster_10mm_5mm": (BEFORE, (lambda r: arm_cells(r, 0.010, 0.005),)),
    "arm_cluster_15mm_4mm": (BEFORE, (lambda r: arm_cells(r, *CELLS),)),
    "arm_cluster_20mm_4mm": (BEFORE, (lambda r: arm_cells(r, 0.020, 0.004),)),
    "no_arm": (BEFORE, (lambda r: remove_bodies(r, is_arm),)),
    "nothing": (BEFORE, (lambda r: remove_bodies(r, lambda n: True),)),
    "arm_15_4+ground_quad": (BEFORE, (lambda r: arm_cells(r, *CELLS), ground_quad)),
    "arm_15_4+lambert": (
        BEFORE | {"shader": render.LEAN_SHADER},
        (lambda r: arm_cells(r, *CELLS),),
    ),  # fmt: skip
    "lean": (LEAN, ()),
    "lean+trivial": (LEAN | {"shader": "trivial"}, ()),
    "lean+no_lights": (LEAN, (remove_lights,)),
    "lean+no_table": (LEAN, (lambda r: remove_bodies(r, is_table),)),
    "lean+no_ground": (LEAN, (lambda r: remove_bodies(r, is_ground),)),
    "lean+no_cubes": (LEAN, (lambda r: remove_bodies(r, is_cube),)),
    "lean+no_arm": (LEAN, (lambda r: remove_bodies(r, is_arm),)),
    "lean+nothing": (LEAN, (lambda r: remove_bodies(r, lambda n: True),)),
    "lean+size_16": (LEAN | {"width": 16, "height": 16}, ()),
}


def _register_trivial() -> None:
    """SAPIEN's trivial shader pack (base colour only, no lights) as ManiSkill knows packs."""
    from mani_skill.render.shaders import PREBUILT_SHADER_CONFIGS, ShaderConfig

    PREBUILT_SHADER_CONFIGS.setdefault(
        "trivial", ShaderConfig("trivial", texture_names={"Color": ["rgb"]})
    )


def make(knob: str) -> Renderer:
    _register_trivial()
    kwargs, applied = KNOBS[knob]
    size = {"width": 84, "height": 84} | {k: v for k, v in kwargs.items() if k in SIZE}
    extra = {k: v for k, v in kwargs.items() if k not in SIZE}
    r = Renderer("stack_cube", "panda", size["width"], size["height"], CAMERAS, **extra)
    for apply in applied:
        apply(r)
    return r


def frame(r: Renderer, state: np.ndarray) -> dict[str, float]:
    """Seconds of the scene set and of each camera's picture."""
    t0 = time.perf_counter()
    r._set_scene(state)
    out = {"set": time.perf_counter() - t0}
    for c in CAMERAS:
        cam = r._render_cameras[c]
        t0 = time.perf_counter()
        cam.take_picture()
        cam.get_picture("Color")
        out[c] = time.perf_counter() - t0
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--knobs", nargs="*", default=list(KNOBS))
    p.add_argument("--out", default=None)
    args = p.parse_args()
    knobs = ["baseline"] + [k for k in args.knobs if k != "baseline"]
    renderers = {k: make(k) for k in knobs}
    xs = states(args.frames)
    for r in renderers.values():
        frame(r, xs[0])  # first picture: buffers allocated, pipelines compiled
    times: dict[str, dict[str, list[float]]] = {
        k: {"set": [], **{c: [] for c in CAMERAS}} for k in knobs
    }
    for i, state in enumerate(xs):
        order = knobs[i % len(knobs) :] + knobs[: i % len(knobs)]  # rotated each frame
        for k in order:
            for part, s in frame(renderers[k], state).items():
                times[k][part].append(s)
    med = {k: {part: float(np.median(v)) * 1e3 for part, v in t.items()} for k, t in times.items()}
    rows = []
    for k in knobs:
        row = {"knob": k}
        for part in ("set", *CAMERAS):
            row[f"ms_{part}"] = round(med[k][part], 2)
            row[f"ratio_{part}"] = round(med["baseline"][part] / med[k][part], 2)
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.out:
        result = {
            "frames": args.frames,
            **machine(),
            "LP_NUM_THREADS": os.environ.get("LP_NUM_THREADS"),
            "rows": rows,
        }
        Path(args.out).write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
