"""Milliseconds per camera image of the observe stage's renderers, per back end, camera set,
shader and size, and MB of stored (zstd) images per 1000 demos; written to
metrics/benchmarks/observe.json.

States come from episodes of random arm motions (every step's stored state, as a store
holds them), ``--steps`` steps each; each setup renders every state once after one warm-up
picture. MB per 1000 demos: the images written as the observe stage writes them (chunked
along the steps, zstd), per step, times ``--steps`` (stack_cube's generated demos are ~110
steps long).

    python benchmarks/observe.py --episodes 2 --steps 110
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from mimicgen_pipe import backends
from mimicgen_pipe.data.store import store_writer

BACKENDS = {"maniskill": "stack_cube", "pybullet": "stack"}
CAMERA_SETS = (("agentview",), ("eye_in_hand",), ("agentview", "eye_in_hand"))
SIZES = (84, 128)
# ManiSkill: SAPIEN's shaders on the full scene, and "lean": the stages' renderer (the lean
# scene and shader, mimicgen_pipe/backends/maniskill/render.py; benchmarks/render.py)
SHADERS = {"maniskill": ("default", "minimal", "lean"), "pybullet": ("tiny_renderer",)}


def random_states(backend: str, task: str, episodes: int, steps: int) -> np.ndarray:
    """(episodes * steps, state dim) stored states of random arm motions from D0 scenes."""
    env = backends.make_env(backend, task, "panda")
    rng = np.random.default_rng(0)
    states = []
    for k in range(episodes):
        env.reset(seed=k, variant="D0")
        for t in range(steps):
            states.append(env.get_state())
            grip = 1.0 if t < steps // 2 else -1.0
            env.step(np.r_[rng.uniform(-0.6, 0.6, 6), grip].astype(np.float32))
    env.close()
    return np.asarray(states)


def renderer(backend: str, task: str, size: int, cameras: tuple[str, ...], shader: str):
    if backend == "maniskill":
        from mimicgen_pipe.backends.maniskill.render import Renderer

        if shader == "lean":
            return Renderer(task, "panda", size, size, cameras)
        return Renderer(task, "panda", size, size, cameras, shader=shader, lean=False)
    from mimicgen_pipe.backends.pybullet.render import Renderer

    return Renderer(task, "panda", size, size, cameras)


def stored_mb(images: dict[str, np.ndarray]) -> float:
    """MB the images take in a store, written as the observe stage writes them."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "s.zarr"
        n = len(next(iter(images.values())))
        with store_writer(path, "generated", np.array([n]), {}) as w:
            for camera, value in images.items():
                rows = w.rows(f"obs/{camera}_image", value.shape[1:], np.uint8)
                rows.append(value)
                rows.close()
        size = sum(f.stat().st_size for f in (path / "data").rglob("*") if f.is_file())
    return size / 2**20


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=2, help="episodes per back end")
    p.add_argument("--steps", type=int, default=110, help="steps per episode")
    p.add_argument("--out", default="metrics/benchmarks/observe.json")
    args = p.parse_args()
    rows, sizes = [], {}
    for backend, task in BACKENDS.items():
        states = random_states(backend, task, args.episodes, args.steps)
        for size in SIZES:
            for shader in SHADERS[backend]:
                for cameras in CAMERA_SETS:
                    r = renderer(backend, task, size, cameras, shader)
                    r.images(states[0])  # first picture: buffers allocated
                    r.seconds = dict.fromkeys(cameras, 0.0)
                    t0 = time.perf_counter()
                    images = [r.images(s) for s in states]
                    wall = time.perf_counter() - t0
                    r.close()
                    n = len(states)
                    row = {
                        "backend": backend, "size": size, "shader": shader,
                        "cameras": "+".join(cameras),
                        "ms_per_state": round(1e3 * wall / n, 1),
                        "ms_per_image": round(1e3 * wall / n / len(cameras), 1),
                    } | {f"ms_{c}": round(1e3 * r.seconds[c] / n, 1) for c in cameras}  # fmt: skip
                    rows.append(row)
                    print(json.dumps(row))
                    if len(cameras) == 2 and shader == SHADERS[backend][-1]:
                        stacked = {c: np.stack([im[c] for im in images]) for c in cameras}
                        per_step = stored_mb(stacked) / len(states)
                        sizes[f"{backend}_{size}"] = round(per_step * args.steps * 1000, 1)
    result = {
        "episodes": args.episodes,
        "steps_per_episode": args.steps,
        "cpus": os.cpu_count(),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "timings": rows,
        "mb_per_1000_demos_both_cameras": sizes,
    }
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result["mb_per_1000_demos_both_cameras"]), "->", args.out)


if __name__ == "__main__":
    main()
