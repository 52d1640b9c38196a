"""Memory of the train stage's data loading: peak resident memory of reading a generated
store into training and validation episodes, per training episode, for

    (a) 1,000 demos of a 1,000-episode store,
    (b) 1,000 demos of a 10,000-episode store (must not grow with the unused episodes),
    (c) 10,000 demos of a 10,000-episode store,

    python benchmarks/train_memory.py [--dir /tmp/train_memory]
        [--json metrics/benchmarks/train_memory.json] [--read-store]

The stores are synthetic but have the schema the generate stage writes for StackCube (every
data/ and meta/episodes/ array, dtypes and widths as written, 120-150 steps per episode;
random values, so they compress worse than real ones: a 1,000-episode store is ~90 MB
on disk against the real ~43 MB). They are written once into ``--dir`` and kept there.

Each case runs in a fresh process: after its imports the kernel's peak-RSS mark is reset
(/proc/self/clear_refs), then mimicgen_pipe.learn.training.load_training_data runs as the train
stage calls it; the figure is the peak (VmHWM) minus the resident memory before the call.
A first load of 2 demos runs before it, paying the once-per-process costs (zarr's event
loop, Arrow's decoder: ~9 MB), which are printed apart as "fixed".
``--read-store`` also measures, for comparison, the whole-store read that training used
before (read_store, then the observation/action arrays assembled and split). Prints a
table and writes the figures as JSON.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mimicgen_pipe.core.observations import observation_dims  # noqa: E402
from mimicgen_pipe.data.store import write_store  # noqa: E402

OBJECTS = ("cubeA", "cubeB")
STATE_WIDTH = 70  # ManiSkill StackCube's flat env state (actors and the arm), float32
SPLIT_SEED = 0  # the train stage's
CASES = (("a", 1000, 1000), ("b", 10_000, 1000), ("c", 10_000, 10_000))


def schema() -> dict[str, tuple[tuple[int, ...], str]]:
    """data/ key -> (row shape, dtype) as the generator records StackCube with a Panda."""
    out = {
        "actions": ((7,), "float32"),
        "eef_pose": ((7,), "float64"),
        "target_pose": ((7,), "float64"),
        "env_state": ((STATE_WIDTH,), "float32"),
        "gripper": ((), "float32"),
        "subtask_signals/grasp_cubeA": ((), "bool"),
        "subtask_signals/cubeA_on_cubeB": ((), "bool"),
    }
    out |= {f"object_poses/{o}": ((7,), "float64") for o in OBJECTS}
    out |= {f"obs/{k}": ((w,), "float32") for k, w in observation_dims(OBJECTS).items()}
    return out


class LazyEpisode(Mapping):
    """An episode whose arrays are made when read, each from its own seed: write_store then
    holds one key of every episode at a time, not the whole store in memory."""

    SCHEMA = schema()
    KEYS = list(SCHEMA)

    def __init__(self, seed: int) -> None:
        self.seed = seed
        self.length = int(np.random.default_rng([seed, 0]).integers(120, 151))

    def __getitem__(self, key: str) -> np.ndarray:
        shape, dtype = self.SCHEMA[key]
        rng = np.random.default_rng([self.seed, 1 + self.KEYS.index(key)])
        if dtype == "bool":
            return rng.random((self.length, *shape)) < 0.5
        return rng.normal(size=(self.length, *shape)).astype(dtype)

    def __iter__(self) -> Iterator[str]:
        return iter(self.KEYS)

    def __len__(self) -> int:
        return len(self.KEYS)


def synthetic_store(path: Path, n_episodes: int) -> Path:
    """A generated-kind store of ``n_episodes`` (all successful) with the real schema."""
    if (path / "zarr.json").exists():
        return path
    rng = np.random.default_rng(n_episodes)
    n = n_episodes
    episodes = {
        "seed": np.arange(n, dtype=np.int64),
        "success": np.ones(n, bool),
        "source_demo": rng.integers(0, 10, (n, 2)),
        "initial_object_poses": rng.normal(size=(n, len(OBJECTS), 7)),
        "initial_state": rng.normal(size=(n, STATE_WIDTH)).astype(np.float32),
        "failure_reason": np.full(n, -1, np.int64),
        "ik_failure": np.zeros(n, bool),
    }
    attrs = {
        "run_id": f"synthetic{n}",
        "task": "stack_cube",
        "variant": "D0",
        "backend": "maniskill",
        "robot": "panda",
        "control_mode": "pd_ee_delta_pose",
        "control_freq": 20,
        "objects": list(OBJECTS),
        "subtasks": ["grasp_cubeA", "place_on_cubeB"],
    }
    steps = [LazyEpisode(i) for i in range(n)]
    return write_store(path, "generated", steps, episodes, attrs)


def _status(field: str) -> int:
    """A /proc/self/status figure in bytes (VmRSS, VmHWM)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) * 1024
    raise RuntimeError(f"{field} not in /proc/self/status")


def _read_store_then_split(path: Path, keys: list[str], num_demos: int) -> tuple:
    """What the train stage did before partial reads: the whole store in memory, then the
    observations concatenated and split."""
    from mimicgen_pipe.data.store import read_store
    from mimicgen_pipe.learn.training import SequenceData, split_episodes, subset

    store = read_store(path, required=["actions"], kind="generated")
    keep = np.flatnonzero(store.episodes["success"])[:num_demos]
    starts, ends = store.episode_starts, store.episode_ends
    index = np.concatenate([np.arange(starts[i], ends[i]) for i in keep])
    n = len(store.data["actions"])
    obs = np.concatenate(
        [store.data[f"obs/{k}"].reshape(n, -1)[index] for k in keys], axis=1
    ).astype(np.float32)
    data = SequenceData(
        obs, store.data["actions"][index].astype(np.float32), np.cumsum(ends[keep] - starts[keep])
    )
    tr, va = split_episodes(len(keep), 0.1, np.random.default_rng(SPLIT_SEED))
    return store, data, subset(data, tr), subset(data, va)


def measure(path: Path, num_demos: int, reader: str) -> dict[str, float]:
    """Run in a fresh process: peak and retained memory of one load."""
    import pyarrow  # noqa: F401  (imported by the partial reader: a fixed cost, not data)
    import torch  # noqa: F401  (the train stage has it loaded)

    from mimicgen_pipe.learn.training import load_training_data

    keys = list(observation_dims(OBJECTS))

    def reset_peak() -> int:
        try:
            Path("/proc/self/clear_refs").write_text("5")  # peak RSS := current RSS
        except OSError as exc:
            raise SystemExit(f"cannot reset the peak-RSS mark ({exc}); run on Linux") from exc
        return _status("VmRSS")

    # a first load of 2 demos pays what any load pays once (zarr's event loop and codec
    # registry, Arrow's decoder): measured apart, as fixed
    before = reset_peak()
    load_training_data(path, keys, 2, 0.1, SPLIT_SEED, kind="generated")
    fixed = _status("VmHWM") - before
    before = reset_peak()
    t0 = time.perf_counter()
    if reader == "partial":
        data = load_training_data(path, keys, num_demos, 0.1, SPLIT_SEED, kind="generated")
        parts = (data.train, data.val)
    else:
        *_, train, val = _read_store_then_split(path, keys, num_demos)
        parts = (train, val)
    seconds = time.perf_counter() - t0
    peak, after = _status("VmHWM"), _status("VmRSS")
    episodes = sum(p.n_episodes for p in parts)
    assert episodes == num_demos, episodes
    return {
        "peak_bytes": peak - before,
        "fixed_bytes": fixed,
        "retained_bytes": after - before,
        "array_bytes": sum(p.obs.nbytes + p.actions.nbytes for p in parts),
        "steps": sum(len(p.obs) for p in parts),
        "seconds": seconds,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dir", default="/tmp/train_memory", help="where the stores are kept")
    p.add_argument("--json", default=str(REPO / "metrics/benchmarks/train_memory.json"))
    p.add_argument("--read-store", action="store_true", help="also the whole-store read")
    p.add_argument(
        "--measure", nargs=3, metavar=("STORE", "NUM_DEMOS", "READER"), help=argparse.SUPPRESS
    )
    args = p.parse_args()
    if args.measure:  # the child process of one case
        store, num_demos, reader = args.measure
        print(json.dumps(measure(Path(store), int(num_demos), reader)))
        return

    folder = Path(args.dir)
    folder.mkdir(parents=True, exist_ok=True)
    stores = {}
    for n in sorted({c[1] for c in CASES}):
        t0 = time.perf_counter()
        stores[n] = synthetic_store(folder / f"stack_cube_{n}.zarr", n)
        size = sum(f.stat().st_size for f in stores[n].rglob("*") if f.is_file())
        print(
            f"store of {n} episodes: {size / 1e6:.0f} MB on disk ({time.perf_counter() - t0:.0f} s)"
        )
    readers = ["partial"] + (["read_store"] if args.read_store else [])
    rows = []
    print(f"{'case':5} {'reader':10} {'store':>7} {'demos':>6} {'peak MB':>8} {'kB/episode':>10} "
          f"{'retained MB':>11} {'arrays MB':>9} {'fixed MB':>8} {'s':>6}")  # fmt: skip
    for reader in readers:
        for case, n_store, num_demos in CASES:
            cmd = [sys.executable, __file__, "--measure", str(stores[n_store]), str(num_demos)]
            res = subprocess.run([*cmd, reader], capture_output=True, text=True, check=True)
            m = json.loads(res.stdout.strip().splitlines()[-1])
            row = {"case": case, "reader": reader, "store_episodes": n_store,
                   "num_demos": num_demos, **m,
                   "peak_bytes_per_episode": m["peak_bytes"] / num_demos}  # fmt: skip
            rows.append(row)
            print(f"{case:5} {reader:10} {n_store:7d} {num_demos:6d} {m['peak_bytes'] / 1e6:8.1f} "
                  f"{row['peak_bytes_per_episode'] / 1e3:10.1f} {m['retained_bytes'] / 1e6:11.1f} "
                  f"{m['array_bytes'] / 1e6:9.1f} {m['fixed_bytes'] / 1e6:8.1f} "
                  f"{m['seconds']:6.1f}")  # fmt: skip
    Path(args.json).write_text(json.dumps({"cases": rows}, indent=1) + "\n")
    print(f"-> {args.json}")


if __name__ == "__main__":
    main()
