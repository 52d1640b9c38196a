"""Source demos (the demonstrations MimicGen generates from), recorded on D0: drawn from the
back end's demonstrator or from a file, each replayed on the simulator and kept when its
replay succeeds, so that every kept demo is one the simulator itself reproduces."""

from __future__ import annotations

import functools
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from mimicgen_pipe.core.contracts import Env
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import TaskSpec
from mimicgen_pipe.data.params import SourceParams
from mimicgen_pipe.method.generation import replay_actions
from mimicgen_pipe.sources.source_files import Demonstrator, source_episodes

# the demonstrator draws seeds until num_demos demos replay to success, at most this many
# seeds per demo asked for (plug_charger, the hardest planner here, needs about 4.5)
SEEDS_PER_DEMO = 20

# (demos wanted, first reset seed, source.from_file, a scratch directory) -> (demos, each
# with its reset seed, initial_state and actions (T, 7) as contracts.SourceEpisode; seeds the
# demonstrator dropped without a usable demo; seeds it tried, 0 for a file)
DrawDemos = Callable[[int, int, str | None, Path], tuple[Sequence[Any], int, int]]


@dataclass(frozen=True)
class SourceRecording:
    """The kept source demos: each one's recorded steps (generation.replay_actions), reset
    seed and initial object poses (n_objects, 4, 4), world frame [m]; and how the recording
    went: seeds the demonstrator tried, seeds it dropped without a usable demo, demos that
    failed on replay."""

    steps: list[dict[str, np.ndarray]]
    seeds: list[int]
    initial_object_poses: list[np.ndarray]
    seeds_tried: int
    demonstrator_failures: int
    replay_failures: int

    def episode_fields(self) -> dict[str, np.ndarray]:
        """meta/episodes of a source store."""
        return {
            "seed": np.asarray(self.seeds, np.int64),
            "success": np.ones(len(self.steps), bool),
            "initial_object_poses": np.stack(self.initial_object_poses),
        }

    def metrics(self) -> dict[str, Any]:
        return {
            "demos": len(self.steps),
            "dropped_planner": int(self.demonstrator_failures),
            "dropped_replay": int(self.replay_failures),
            "mean_length": float(np.mean([len(s["actions"]) for s in self.steps])),
            "demonstrator_seeds": int(self.seeds_tried),
        }


@dataclass(frozen=True)
class SourceJob:
    """One source run, checked (mimicgen_pipe.stages.source.resolve): ``source.num_demos``
    demos of task ``spec`` on back end ``backend`` (its name) with arm source.robot, drawn
    from the back end's ``demonstrator`` or from source.from_file (``brought_in``: that
    file's identity for the metrics, source_inputs.file_identity; empty for the
    demonstrator) and recorded on an env of ``make_env``; written as the source store ``out``
    (``data_params``: the params that shape it, recorded in its attrs) and the metrics JSON
    ``metrics_path``."""

    spec: TaskSpec
    backend: str
    source: SourceParams
    make_env: Callable[[], Env]
    demonstrator: Demonstrator
    brought_in: Mapping[str, str]
    data_params: Mapping[str, Any]
    out: Path
    metrics_path: Path

    @property
    def inputs(self) -> list[str]:
        """The files it reads: source.from_file and the JSON beside it (none for the
        demonstrator)."""
        f = self.source.from_file
        return [f, str(Path(f).with_suffix(".json"))] if f else []


def record_source_demos(job: SourceJob, env: Env) -> SourceRecording:
    """``source.num_demos`` demos of the job's task recorded on ``env`` (its objects in the
    spec's order, and its arms): drawn from reset seeds source.seed on (or source.from_file's;
    source_files.source_episodes), each replayed and kept if it succeeds; a demo that fails
    on replay is replaced by one from the demonstrator's next seeds, up to SEEDS_PER_DEMO
    seeds per demo wanted. The draw gets a scratch directory beside the job's ``out``, named
    as its temporaries, so that the next run removes it if this one is killed before it can.

    Raises InputError when no demo succeeds on replay, or when the demonstrator gives fewer
    than source.num_demos within its seeds (a file gives what it has)."""
    source, task, out = job.source, job.spec.name, job.out
    objects, arms = job.spec.objects, job.spec.arms
    draw: DrawDemos = functools.partial(source_episodes, job.backend, job.demonstrator, env)
    steps, seeds, init_poses = [], [], []
    demonstrator_failures = replay_failures = seeds_tried = 0
    while seeds_tried < SEEDS_PER_DEMO * source.num_demos:
        with tempfile.TemporaryDirectory(prefix=f".{out.name}.tmp-", dir=out.parent) as tmp:
            episodes, failures, tried = draw(
                source.num_demos - len(steps),
                source.seed + seeds_tried,
                source.from_file,
                Path(tmp),
            )
        demonstrator_failures += failures
        seeds_tried += tried
        for ep in tqdm(episodes, desc="source: replaying demos", unit="demo"):
            env.set_state(ep.initial_state)
            obj = env.object_poses()
            recorded, success = replay_actions(env, ep.initial_state, ep.actions, objects, arms)
            if not success:
                replay_failures += 1
                continue
            steps.append(recorded)
            seeds.append(ep.seed)
            init_poses.append(np.stack([obj[o] for o in objects]))
        if len(steps) == source.num_demos or tried == 0:  # done, or a file: nothing more to draw
            break
    if not steps:
        raise InputError(f"{source.from_file or task}: no source demo succeeded when replayed")
    if len(steps) < source.num_demos and source.from_file is None:
        raise InputError(
            f"{task}: the demonstrator gave {len(steps)} of source.num_demos = "
            f"{source.num_demos} demos that succeed on replay in {seeds_tried} seeds from "
            f"source.seed = {source.seed} ({demonstrator_failures} seeds without a usable demo, "
            f"{replay_failures} demos failed on replay); ask for fewer demos or look at the "
            "demonstrator"
        )
    return SourceRecording(
        steps, seeds, init_poses, seeds_tried, demonstrator_failures, replay_failures
    )
