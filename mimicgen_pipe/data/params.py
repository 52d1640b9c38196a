"""params.yaml, validated into frozen dataclasses before any work.

Every knob of every stage lives in params.yaml; a wrong type, an out-of-range value or an
unknown key stops the stage with one message naming the key.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import reprlib
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.noise_levels import level_error
from mimicgen_pipe.core.registry import choices
from mimicgen_pipe.core.transit import PlannerSettings
from mimicgen_pipe.core.yamlfile import load_yaml


@dataclass(frozen=True)
class SourceParams:
    """num_demos: successful source demos wanted (D0). seed: first reset seed. robot: the arm
    the source demos are recorded with. from_file: a ManiSkill trajectory .h5
    (pd_ee_delta_pose), or a robomimic .hdf5 of this back end and task (as the export stage
    writes), to use instead of the demonstrator; null to use the demonstrator."""

    num_demos: int = 10
    seed: int = 0
    robot: str = "panda"
    from_file: str | None = None


@dataclass(frozen=True)
class GenerateParams:
    """Generation knobs (paper M.6 defaults). mode "guarantee" runs until num_demos
    successes (failing loudly after max_attempts); "fixed_attempts" runs exactly
    max_attempts attempts. selection: a selection strategy of mimicgen_pipe.method.selection.
    executor: where attempts run, an executor of mimicgen_pipe.run.executors: ``local`` (a pool
    of ``workers`` simulator processes here) or ``ray`` (Ray tasks; see RayParams). Neither
    workers nor executor changes the data. transit: how the arm reaches each segment:
    "linear" interpolation (paper M.2) or a "planned" collision-free path (ManiSkill only;
    mimicgen_pipe.core.transit), with the planner's knobs in ``planner``. num_envs: scenes each
    worker steps together in one batched simulation (mimicgen_pipe.method.batched; ManiSkill on
    maniskill.sim_backend physx_cuda); 1: one attempt at a time."""

    variants: list[str] = field(default_factory=lambda: ["D0", "D1"])
    num_demos: int = 1000
    mode: Literal["guarantee", "fixed_attempts"] = "guarantee"
    max_attempts: int = 3000
    action_noise: float = 0.05
    n_interp: int = 5
    n_fixed: int = 0
    selection: str = "random"
    nn_k: int = 3
    per_subtask: bool = False
    seed: int = 0
    workers: int = 2
    executor: str = "local"
    robot: str = "panda"
    transit: Literal["linear", "planned"] = "linear"
    planner: PlannerSettings = field(default_factory=PlannerSettings)
    num_envs: int = 1


@dataclass(frozen=True)
class PoseNoiseParams:
    """Pose-estimation error (paper T), applied to the object poses of the source demos (the
    pose_noise stage) and to those the generator observes in each new scene. level: none,
    L1 (5 mm / 5 deg), L2 (10 mm / 10 deg) or [position_mm, rotation_deg]. seed: seed of the
    noise on the source demos (generation draws its own from each attempt's seed)."""

    level: str | list[float] = "none"
    seed: int = 0


@dataclass(frozen=True)
class CoverageParams:
    """Support coverage (paper Q): bins per dimension (x, y, yaw) of every object's initial
    pose over the variant's reset bounds."""

    bins: int = 3


@dataclass(frozen=True)
class TrainProfile:
    """BC-RNN size and schedule (paper N; robomimic's BC-RNN). hidden x layers LSTM, windows
    of seq_len steps, Adam at lr, epochs x steps_per_epoch gradient steps, a checkpoint every
    checkpoint_every epochs; each training seed is its own run. With ``cameras``, an image
    policy (mimicgen_pipe.learn.policy.ImageEncoder per camera)."""

    hidden: int = 400
    layers: int = 2
    seq_len: int = 10
    batch_size: int = 100
    lr: float = 1e-3
    lr_schedule: Literal["constant", "cosine"] = "constant"
    epochs: int = 2000
    steps_per_epoch: int = 100
    checkpoint_every: int = 50
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    threads: int = 0  # torch CPU threads per training; 0 keeps torch's default
    device: Literal["cpu", "cuda", "auto"] = "auto"  # auto: cuda when available
    # an image policy's (the paper's image agents): the cameras it sees, obs/<camera>_image
    # of an observed store; none: a low-dim policy, and the keys below are unused
    cameras: list[str] = field(default_factory=list)
    image_size: list[int] = field(default_factory=lambda: [84, 84])  # (height, width) [px]
    shift: float = 0.1  # pixel-shift augmentation: up to this share of each dimension
    channels: int = 32  # convolution channels of each camera's encoder
    keypoints: int = 32  # spatial-softmax keypoints of each camera's encoder
    image_features: int = 64  # features each camera's encoder gives the LSTM


@dataclass(frozen=True)
class TrainParams:
    """profile: which of the profiles below trains (cpu_image: an image policy). num_demos:
    generated demos used (the first N kept episodes; the source policy uses every source
    demo). obs_keys: the policy's observation, keys of obs/ in the stores
    (mimicgen_pipe.core.observations); None: the task's own (its spec's default_obs_keys), filled
    in by mimicgen_pipe.stages.stage_params. workers: trainings side by side (one process each) when
    a stage trains several policies or seeds."""

    profile: Literal["cpu", "paper", "cpu_image"] = "cpu"
    workers: int = 1
    num_demos: int = 1000
    obs_keys: list[str] | None = None
    val_fraction: float = 0.1
    cpu: TrainProfile = field(
        default_factory=lambda: TrainProfile(
            hidden=100, epochs=200, checkpoint_every=25, seeds=[0], threads=1, device="cpu"
        )
    )
    paper: TrainProfile = field(default_factory=TrainProfile)
    cpu_image: TrainProfile = field(
        default_factory=lambda: TrainProfile(
            batch_size=16, epochs=400, checkpoint_every=50, threads=2, device="cpu",
            cameras=["agentview", "eye_in_hand"], channels=16,
        )
    )  # fmt: skip

    @property
    def active(self) -> TrainProfile:
        return getattr(self, self.profile)


@dataclass(frozen=True)
class EvaluateParams:
    """episodes: rollouts per checkpoint. every_epochs: the checkpoints rolled out are those
    of every ``every_epochs``-th epoch and the last (a multiple of the training's
    checkpoint_every). seed: evaluation seed stream (reset seeds are disjoint from
    generation's whatever its value). workers, executor: as for generate."""

    episodes: int = 50
    every_epochs: int = 50
    seed: int = 0
    workers: int = 2
    executor: str = "local"


@dataclass(frozen=True)
class ExportParams:
    """formats: what the export stage writes for each generated store, exporters of
    mimicgen_pipe.formats.exporters (robomimic HDF5, LeRobot dataset, ManiSkill trajectory files).
    workers: simulator processes replaying episodes for the ManiSkill format. step_success:
    evaluate the task's success after every step on the back end, for the rewards and dones
    (on a back end that restores states cheaply, contracts.Backend; false, or elsewhere: only
    each episode's last step is known)."""

    formats: list[str] = field(default_factory=lambda: ["robomimic", "lerobot", "maniskill"])
    workers: int = 2
    step_success: bool = True


@dataclass(frozen=True)
class RenderParams:
    """episodes: videos of the first N kept and the first N failed episodes per variant.
    width, height: frame size [px] before the caption band."""

    episodes: int = 2
    width: int = 320
    height: int = 240


@dataclass(frozen=True)
class ObserveParams:
    """cameras: the camera images the observe stage renders from each step's stored state
    (mimicgen_pipe/core/cameras.py: agentview, eye_in_hand). height, width: image size [px]
    (84: the paper's). episodes: the first N episodes of the store (null: all). workers: renderer
    processes (the images are the same for any number)."""

    cameras: list[str] = field(default_factory=lambda: ["agentview", "eye_in_hand"])
    height: int = 84
    width: int = 84
    episodes: int | None = None
    workers: int = 2


@dataclass(frozen=True)
class RayParams:
    """address: the Ray cluster that stages with ``executor: ray`` run on (``auto``,
    or the GCS's ``host:port``; Ray's token authentication on, see docs/scale-out.md);
    null: the ``RAY_ADDRESS`` environment variable when set, else a Ray started on this
    machine (loopback only) with the stage's ``workers`` CPUs."""

    address: str | None = None


@dataclass(frozen=True)
class ManiSkillParams:
    """lean_step: the ManiSkill back end steps with its lean control step
    (mimicgen_pipe/backends/maniskill/lean.py: the same simulation, bit for bit, without ManiSkill's
    per-step bookkeeping); false: ManiSkill's own ``env.step`` and ``evaluate()``, for checking.
    sim_backend: ManiSkill's simulation for generation: physx_cpu (one scene per process) or
    physx_cuda (generate.num_envs scenes on the GPU, mimicgen_pipe/backends/maniskill/batch.py)."""

    lean_step: bool = True
    sim_backend: Literal["physx_cpu", "physx_cuda"] = "physx_cpu"


@dataclass(frozen=True)
class TransferParams:
    """The robot-transfer matrix of transfer/dvc.yaml (paper E): every task x variant x robot
    is generated from the same Panda source demos, ``attempts`` fixed attempts each, on
    ``backend`` (a back end under mimicgen_pipe/backends/); the other generation knobs come from
    ``generate``. maniskill_robots: arms the main ManiSkill task is also generated with
    (``attempts`` each), from the main run's source demos. policy_tasks: tasks of ``tasks`` whose D0
    policy trains on ``generate.num_demos`` demos generated with ``generate.robot``, with
    seeds 0..``policy_seeds``-1, against Table P.1's mean ± std over 3 seeds."""

    backend: str = "pybullet"
    tasks: list[str] = field(default_factory=lambda: ["stack", "stack_three", "square_peg"])
    variants: list[str] = field(default_factory=lambda: ["D0", "D1"])
    robots: list[str] = field(default_factory=lambda: ["panda", "iiwa", "xarm6"])
    maniskill_robots: list[str] = field(default_factory=lambda: ["panda", "xarm6"])
    attempts: int = 200
    policy_tasks: list[str] = field(default_factory=list)
    policy_seeds: int = 3


@dataclass(frozen=True)
class PlannedTransitParams:
    """The transit pipeline (transit/dvc.yaml): ``attempts`` fixed attempts with linear and
    with planned transit, on the D0 of each task of ``tasks`` and on stack_cube_wall's
    variant wall, at action noise ``action_noise``; policies on ``policy_demos`` kept demos
    of each transit on the wall."""

    tasks: list[str] = field(
        default_factory=lambda: ["stack_cube_wall", "pull_cube_tool", "place_sphere"]
    )
    attempts: int = 200
    policy_demos: int = 100
    action_noise: float = 0.025  # the suite's: the paper's 0.05 in ManiSkill's action units


@dataclass(frozen=True)
class ScalingParams:
    """Policies on more or fewer generated demos (suite/dvc.yaml; paper Fig. P.1, right): one
    store of ``demos`` generated demos of ``task`` (a suite task) on ``variant`` (generated
    until that many succeed, giving up after ``max_attempts``), and one policy on the first N
    of them for each N of ``num_demos`` (each at most ``demos``), each evaluated on
    ``variant``. task null: no comparison (suite/dvc.yaml's scaling stages need one)."""

    task: str | None = None
    variant: str = "D0"
    demos: int = 5000
    num_demos: list[int] = field(default_factory=lambda: [200, 1000, 5000])
    max_attempts: int = 15_000


@dataclass(frozen=True)
class PolicyData:
    """A store the suite's policies train on: generate.num_demos kept demos of ``task`` on
    reset variant ``variant`` (data/generated/<task>_<variant>_train.zarr)."""

    task: str
    variant: str


@dataclass(frozen=True)
class Evaluation:
    """One policy of the suite rolled out: ``task``'s policy on ``data`` ("source", or a
    reset variant's policy data) on reset variant ``variant``."""

    task: str
    data: str
    variant: str


@dataclass(frozen=True)
class SuiteParams:
    """The task suite (suite/dvc.yaml): every task x variant generated from its own source
    demos, ``attempts`` fixed attempts each, on ``backend``, with action noise
    ``action_noise``; the other generation knobs come from ``generate``. The default 0.025
    is the paper's sigma 0.05 in physical units: robosuite's OSC moves 0.05 m per action
    unit, ManiSkill's pd_ee_delta_pose 0.1 m, so both mean 2.5 mm per step.
    object_transfer: tasks also generated on their O1 variant (paper F: another object,
    the same source demos).
    policy_tasks: tasks with policies on D0 and D1 (source, D0 and D1 data; paper P.1);
    d0_policy_tasks: tasks with policies on D0 only (source and D0 data);
    seeded_policy_tasks: tasks with one policy, on D0 data, trained with seeds
    0..``policy_seeds``-1 (the others with the profile's seeds), for a mean ± std over seeds
    as Table P.1's. All among ``tasks``, none in two lists. policy_data: the stores they
    train on, and evaluations: which policy is rolled out on which variant, one stage each,
    named by its key (``<task>-<variant>``, ``<task>-<data>-on-<variant>``).
    robomimic_tasks: tasks, each
    with D0 policy data (in policy_data), on whose 1000 D0 demos robomimic 0.3.0's
    own BC-RNN also trains at our profile's size, with and without its observation
    normalisation (an outside learner beside ours). scaling: the dataset-size comparison
    (ScalingParams). ablation_tasks: tasks on which every run of ``ablations.runs`` is
    made (suite/ablations/dvc.yaml), from the suite's base (its action noise)."""

    backend: str = "maniskill"
    tasks: list[str] = field(default_factory=lambda: ["pull_cube_tool", "place_sphere"])
    variants: list[str] = field(default_factory=lambda: ["D0", "D1", "D2"])
    attempts: int = 200
    action_noise: float = 0.025
    object_transfer: list[str] = field(default_factory=list)
    policy_tasks: list[str] = field(default_factory=list)
    d0_policy_tasks: list[str] = field(default_factory=list)
    seeded_policy_tasks: list[str] = field(default_factory=list)
    policy_seeds: int = 3
    policy_data: dict[str, PolicyData] = field(default_factory=dict)
    evaluations: dict[str, Evaluation] = field(default_factory=dict)
    robomimic_tasks: list[str] = field(default_factory=list)
    scaling: ScalingParams = field(default_factory=ScalingParams)
    ablation_tasks: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class AblationRun:
    """One named generation ablation (the ablation stage): ``what`` it measures, in the
    paper's words and table, and ``changes``, the generate and pose_noise keys it sets over
    the pipeline's own (e.g. ``{generate: {action_noise: 0.0}}``; empty: the base run)."""

    what: str
    changes: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class AblationParams:
    """The paper's generation ablations as stages (dvc.yaml: ablation@<run>): each run of
    ``runs`` is pose_noise -> generate -> coverage with the pipeline's params and the run's
    changes, exactly ``attempts`` attempts on reset variant ``variant``, every run with the
    same attempt seeds unless it changes generate.seed (so that runs see the same scenes)."""

    variant: str = "D1"
    attempts: int = 200
    runs: dict[str, AblationRun] = field(default_factory=dict)


# what an ablation run may change: the keys of the stages it runs, but not the variant, mode
# and attempts that every run shares (ablations.variant, ablations.attempts)
ABLATION_KEYS = {"generate": ("variants", "mode", "max_attempts", "num_demos"), "pose_noise": ()}


@dataclass(frozen=True)
class Params:
    """task and backend: the main pipeline's task and simulator back end (a package under
    mimicgen_pipe/backends/)."""

    task: str = "stack_cube"
    backend: str = "maniskill"
    source: SourceParams = field(default_factory=SourceParams)
    generate: GenerateParams = field(default_factory=GenerateParams)
    pose_noise: PoseNoiseParams = field(default_factory=PoseNoiseParams)
    coverage: CoverageParams = field(default_factory=CoverageParams)
    train: TrainParams = field(default_factory=TrainParams)
    evaluate: EvaluateParams = field(default_factory=EvaluateParams)
    transfer: TransferParams = field(default_factory=TransferParams)
    suite: SuiteParams = field(default_factory=SuiteParams)
    planned_transit: PlannedTransitParams = field(default_factory=PlannedTransitParams)
    export: ExportParams = field(default_factory=ExportParams)
    render: RenderParams = field(default_factory=RenderParams)
    observe: ObserveParams = field(default_factory=ObserveParams)
    ray: RayParams = field(default_factory=RayParams)
    maniskill: ManiSkillParams = field(default_factory=ManiSkillParams)
    ablations: AblationParams = field(default_factory=AblationParams)


_RANGES: dict[str, tuple[float, float]] = {
    "source.num_demos": (1, 10_000),
    "generate.num_demos": (0, 10_000_000),
    "generate.max_attempts": (1, 10_000_000),
    "generate.action_noise": (0.0, 1.0),
    "generate.n_interp": (0, 1000),
    "generate.n_fixed": (0, 1000),
    "generate.nn_k": (1, 10_000),
    "generate.workers": (1, 256),
    "generate.num_envs": (1, 65_536),
    "generate.planner.approach_distance": (0.0, 1.0),
    "generate.planner.clearance": (0.0, 0.2),
    "generate.planner.max_joint_step": (0.001, 0.5),
    "generate.planner.max_iterations": (1, 1_000_000),
    "generate.planner.shortcuts": (0, 100_000),
    "generate.planner.ik_tries": (1, 1000),
    "coverage.bins": (1, 100),
    "source.seed": (0, 2**29),  # reset seeds from 2**30 on are evaluation's
    # the other seeds only seed numpy / torch generators and SeedSequences (generation and
    # evaluation derive reset seeds from theirs, always below 2**31); all of these take any
    # int >= 0, and int32's range keeps a seed usable by every simulator and file format
    "generate.seed": (0, 2**31 - 1),
    "evaluate.seed": (0, 2**31 - 1),
    "pose_noise.seed": (0, 2**31 - 1),
    "train.*.seeds": (0, 2**31 - 1),  # each seed of the list
    "suite.policy_seeds": (1, 100),  # seeds 0..N-1
    "transfer.policy_seeds": (1, 100),
    "train.num_demos": (1, 10_000_000),
    "train.val_fraction": (0.0, 0.5),
    "train.*.hidden": (1, 8192),
    "train.*.layers": (1, 16),
    "train.*.seq_len": (1, 1000),
    "train.*.batch_size": (1, 100_000),
    "train.*.lr": (1e-8, 1.0),
    "train.*.epochs": (1, 1_000_000),
    "train.*.steps_per_epoch": (1, 1_000_000),
    "train.*.checkpoint_every": (1, 1_000_000),
    "train.*.threads": (0, 1024),
    "train.*.image_size": (17, 4096),  # height, width [px]; 17: the encoder's smallest
    "train.*.shift": (0.0, 0.5),
    "train.*.channels": (1, 1024),
    "train.*.keypoints": (1, 1024),
    "train.*.image_features": (1, 8192),
    "train.workers": (1, 256),
    "evaluate.episodes": (1, 100_000),
    "evaluate.every_epochs": (1, 1_000_000),
    "evaluate.workers": (1, 256),
    "export.workers": (1, 256),
    "render.episodes": (0, 1000),
    "render.width": (16, 4096),
    "render.height": (16, 4096),
    "observe.height": (1, 4096),
    "observe.width": (1, 4096),
    "observe.episodes": (1, 10_000_000),
    "observe.workers": (1, 256),
    "transfer.attempts": (1, 10_000_000),
    "suite.attempts": (1, 10_000_000),
    "planned_transit.attempts": (1, 10_000_000),
    "planned_transit.policy_demos": (1, 10_000_000),
    "suite.action_noise": (0.0, 1.0),
    "planned_transit.action_noise": (0.0, 1.0),
    "suite.scaling.demos": (1, 10_000_000),
    "suite.scaling.num_demos": (1, 10_000_000),  # each entry
    "suite.scaling.max_attempts": (1, 10_000_000),
    "ablations.attempts": (1, 10_000_000),
}


def key_range(key: str) -> tuple[float, float] | None:
    """The (low, high) range the params file allows for ``key``, None where it has none."""
    return next((r for p, r in _RANGES.items() if fnmatch.fnmatchcase(key, p)), None)


def range_error(key: str, value: float) -> str | None:
    """Why ``value`` is outside the range of params key ``key`` (as the params file's
    check says it), or None: for a command-line option that stands in for the key."""
    bounds = key_range(key)
    if bounds is not None and not bounds[0] <= value <= bounds[1]:
        return f"expected a value in [{bounds[0]}, {bounds[1]}] (the range of {key}), got {value!r}"
    return None


# Keys whose values need more than a type and a range: key -> why the value is wrong (None
# when it is right).
def _non_empty_unique(value: Any) -> str | None:
    if isinstance(value, list) and not value:
        return "expected at least one entry, got []"
    return _unique(value)


def _unique(value: Any) -> str | None:
    if isinstance(value, list) and len(set(map(str, value))) < len(value):
        return f"expected distinct entries, got {value!r}"
    return None


def _size(value: Any) -> str | None:
    if isinstance(value, list) and len(value) != 2:
        return f"expected [height, width] in pixels, got {_short(value)}"
    return None


def _non_empty_path(value: Any) -> str | None:
    if value == "":
        return "expected a file path or null, got ''"
    return None


def _one_of(known: tuple[str, ...], value: Any) -> str | None:
    if value in known:
        return None
    return f"expected one of {', '.join(map(repr, known))}, got {_short(value)}"


def _each_one_of(known: tuple[str, ...], value: Any) -> str | None:
    bad = [v for v in value if v not in known] if isinstance(value, list) else []
    if bad:
        return f"expected entries among {', '.join(map(repr, known))}, got {_short(bad[0])}"
    return None


# Keys whose valid values are a registry's choices (mimicgen_pipe.core.registry): the modules of
# its package, listed when a params file is checked.
def _backend(value: Any) -> str | None:
    return _one_of(choices("mimicgen_pipe.backends"), value)


def _executor(value: Any) -> str | None:
    return _one_of(choices("mimicgen_pipe.run.executors"), value)


def _selection(value: Any) -> str | None:
    return _one_of(choices("mimicgen_pipe.method.selection"), value)


def _increasing(value: Any) -> str | None:
    if not isinstance(value, list) or not all(type(v) is int for v in value):
        return None  # the type check says what is wrong
    if not value or any(b <= a for a, b in zip(value, value[1:], strict=False)):
        return f"expected a non-empty list in increasing order, got {_short(value)}"
    return None


def _formats(value: Any) -> str | None:
    return _non_empty_unique(value) or _each_one_of(
        choices("mimicgen_pipe.formats.exporters"), value
    )


_CHECKS: dict[str, Callable[[Any], str | None]] = {
    "backend": _backend,
    "transfer.backend": _backend,
    "suite.backend": _backend,
    "generate.executor": _executor,
    "evaluate.executor": _executor,
    "generate.selection": _selection,
    "export.formats": _formats,
    "pose_noise.level": level_error,
    "source.from_file": _non_empty_path,
    "generate.variants": _non_empty_unique,
    "train.obs_keys": _non_empty_unique,
    "observe.cameras": _non_empty_unique,
    # each training seed is its own run, written under its own seed<k>/ folder
    "train.cpu.seeds": _non_empty_unique,
    "train.paper.seeds": _non_empty_unique,
    "train.cpu_image.seeds": _non_empty_unique,
    **{f"train.{p}.cameras": _unique for p in ("cpu", "paper", "cpu_image")},
    **{f"train.{p}.image_size": _size for p in ("cpu", "paper", "cpu_image")},
    "transfer.tasks": _non_empty_unique,
    "transfer.variants": _non_empty_unique,
    "transfer.robots": _non_empty_unique,
    "suite.tasks": _non_empty_unique,
    "suite.policy_tasks": _non_empty_unique,
    "planned_transit.tasks": _non_empty_unique,
    "suite.variants": _non_empty_unique,
    "suite.ablation_tasks": _unique,
    "suite.scaling.num_demos": _increasing,
}


def _describe(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_describe(a) for a in typing.get_args(tp))
    if origin is list:
        return f"a list of {_describe(typing.get_args(tp)[0])}"
    if origin is dict:
        return "a mapping"
    return {
        int: "an integer",
        float: "a number",
        bool: "true/false",
        str: "a string",
        type(None): "null",
    }.get(tp, str(tp))


def _check(value: Any, tp: Any) -> bool:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return value in typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return any(_check(value, a) for a in typing.get_args(tp))
    if origin is list:
        return isinstance(value, list) and all(_check(v, typing.get_args(tp)[0]) for v in value)
    if origin is dict:
        return isinstance(value, dict)
    if tp is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if tp is type(None):
        return value is None
    return isinstance(value, tp)


def _build(cls: type, raw: Any, where: str, path: Path) -> Any:
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        what = f"{where or 'top level'}: expected a mapping, got {_short(raw)}"
        raise InputError(f"{path}: {what}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    # keys may load as numbers or booleans (``1:``, ``yes:``): sorted as text
    unknown = sorted(set(raw) - names, key=str)
    if unknown:
        key = f"{where}.{unknown[0]}" if where else str(unknown[0])
        raise InputError(f"{path}: {key}: unknown key (known: {', '.join(sorted(names))})")
    none = dataclasses.MISSING
    required = [
        f.name for f in dataclasses.fields(cls) if f.default is none and f.default_factory is none
    ]
    missing = [n for n in required if n not in raw]
    if missing:
        key = f"{where}.{missing[0]}" if where else missing[0]
        raise InputError(f"{path}: {key}: missing (a {cls.__name__} has {', '.join(required)})")
    kwargs = {}
    for name in names & set(raw):
        key = f"{where}.{name}" if where else name
        tp, value = hints[name], raw[name]
        if dataclasses.is_dataclass(tp):
            kwargs[name] = _build(tp, value, key, path)
            continue
        if typing.get_origin(tp) is dict and dataclasses.is_dataclass(typing.get_args(tp)[1]):
            # named cells, each a section of its own
            if not isinstance(value, dict):
                raise InputError(f"{path}: {key}: expected a mapping of named cells, got "
                                 f"{_short(value)}")  # fmt: skip
            cell = typing.get_args(tp)[1]
            kwargs[name] = {str(k): _build(cell, v, f"{key}.{k}", path) for k, v in value.items()}
            continue
        why = _CHECKS[key](value) if key in _CHECKS else None
        if why:
            raise InputError(f"{path}: {key}: {why}")
        if not _check(value, tp):
            raise InputError(f"{path}: {key}: expected {_describe(tp)}, got {_short(value)}")
        for pattern, (lo, hi) in _RANGES.items():
            if not fnmatch.fnmatchcase(key, pattern):
                continue
            for v in value if isinstance(value, list) else [value]:
                if v is not None and not lo <= v <= hi:  # None: a key's "none given"
                    each = "each entry " if isinstance(value, list) else ""
                    raise InputError(
                        f"{path}: {key}: expected {each}a value in [{lo}, {hi}], got {v!r}"
                    )
        kwargs[name] = float(value) if tp is float else value
    return cls(**kwargs)


_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxstring, _REPR.maxother = 3, 60, 60


def _short(value: Any, limit: int = 80) -> str:
    """repr of a value from a user's file, cut to ``limit`` characters for a one-line error;
    a few entries per level and a few levels only, so that it never walks a large value."""
    text = _REPR.repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def read_yaml(path: Path, what: str) -> Any:
    """The YAML document at ``path``; InputError naming the file when it is missing
    (``what`` says what was expected there), unreadable, not UTF-8, not valid YAML or has a
    key twice in one mapping (mimicgen_pipe.core.yamlfile)."""
    return load_yaml(path, what)


def load_params(path: str | Path = "params.yaml") -> Params:
    """Read and validate params.yaml; raises InputError naming the file and key."""
    path = Path(path)
    raw = read_yaml(path, "params file")
    hints = typing.get_type_hints(Params)
    sections = [name for name, tp in hints.items() if dataclasses.is_dataclass(tp)]
    if not raw:
        raise InputError(f"{path}: empty; expected the pipeline's params (sections {sections})")
    if isinstance(raw, dict) and not set(raw) & set(sections):
        raise InputError(
            f"{path}: no stage sections; expected at least one of {sections} "
            "(the repository's params.yaml lists every key)"
        )
    params = _build(Params, raw, "", path)
    for name in params.ablations.runs:  # every run's params valid before any work
        ablation_params(params, name, path)
    return params


def ablation_params(params: Params, name: str, path: str | Path = "params.yaml") -> Params:
    """The params of ablation run ``name`` of ``params.ablations`` (read from ``path``):
    its changes over ``params``, on the section's variant and fixed attempts; InputError
    naming the run's key for a change it may not make or a value the key does not take."""
    a = params.ablations
    if name not in a.runs:
        raise InputError(
            f"{path}: ablations.runs: no run {name!r} (runs: {', '.join(a.runs) or 'none'})"
        )
    where = f"ablations.runs.{name}.changes"
    changes = dict(a.runs[name].changes)
    for section, change in changes.items():
        if section not in ABLATION_KEYS:
            raise InputError(
                f"{path}: {where}.{section}: an ablation changes only "
                f"{' and '.join(ABLATION_KEYS)} (the stages it runs)"
            )
        if not isinstance(change, dict):
            raise InputError(f"{path}: {where}.{section}: expected a mapping, got {_short(change)}")
        shared = sorted(set(change) & set(ABLATION_KEYS[section]), key=str)
        if shared:
            raise InputError(
                f"{path}: {where}.{section}.{shared[0]}: every run shares it "
                "(ablations.variant and ablations.attempts set it)"
            )
    shared = {"variants": [a.variant], "mode": "fixed_attempts", "max_attempts": a.attempts}
    changes["generate"] = changes.get("generate", {}) | shared
    sections = {}
    for section, change in changes.items():
        tp = typing.get_type_hints(Params)[section]
        raw = _merged(as_dict(getattr(params, section)), change)
        try:
            sections[section] = _build(tp, raw, section, Path(path))
        except InputError as e:  # name the run's key
            raise InputError(str(e).replace(f"{path}: ", f"{path}: {where}.", 1)) from None
    return dataclasses.replace(params, **sections)


def _merged(base: dict[str, Any], change: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``change``'s keys set, section by section."""
    out = dict(base)
    for key, value in change.items():
        both = isinstance(value, dict) and isinstance(out.get(key), dict)
        out[key] = _merged(out[key], value) if both else value
    return out


def with_overrides(
    params: Params, backend: str | None = None, task: str | None = None, robot: str | None = None
) -> Params:
    """``params`` with a stage's command-line choices of back end, task and generation arm
    (dvc.yaml's robot-transfer matrix runs the same stages on other tasks and arms)."""
    if backend is not None:
        if why := _backend(backend):
            raise InputError(f"--backend: {why}")
        params = dataclasses.replace(params, backend=backend)
    if task is not None:
        params = dataclasses.replace(params, task=task)
    if robot is not None:
        params = dataclasses.replace(
            params, generate=dataclasses.replace(params.generate, robot=robot)
        )
    return params


def as_dict(params: Any) -> dict[str, Any]:
    """Params as plain data, for checkpoints and metrics."""
    return dataclasses.asdict(params)


# Keys that cannot change a stage's data (process counts), left out of what stores record and
# of the params dvc.yaml declares for the stage, so that changing them re-runs nothing.
_NOT_DATA = {
    "generate": ("workers", "executor", "variants"),
    "train": ("workers",),
    "observe": ("workers",),
}


# TrainProfile's keys of an image policy, left out of a low-dim profile's record
_IMAGE_KEYS = ("cameras", "image_size", "shift", "channels", "keypoints", "image_features")


def training_params(train: TrainParams) -> dict[str, Any]:
    """train params as a checkpoint records them: without the worker count, which decides how
    many trainings run side by side, not what any of them learns. The image profile and a
    low-dim profile's image keys are recorded only where they are used, so that low-dim
    checkpoints keep the bytes they had before image policies."""
    t = as_dict(train)
    for key in _NOT_DATA["train"]:
        del t[key]
    if train.profile != "cpu_image":
        del t["cpu_image"]
    for name in ("cpu", "paper", "cpu_image"):
        if name in t and not t[name]["cameras"]:
            for key in _IMAGE_KEYS:
                del t[name][key]
    return t


def data_params(params: Params, stage: Literal["source", "generate", "observe"]) -> dict[str, Any]:
    """The params that shape a stage's output store, as recorded in its attrs: exactly the
    keys dvc.yaml declares for the stage (so the same declared params give the same bytes).
    source: task, backend, source. generate: generate without worker counts and the variant
    list (without num_demos in fixed_attempts mode, where it is unused; without transit and
    planner for linear transit and num_envs for one attempt at a time, so that stores from
    before planned transit and batches keep their bytes), pose_noise, and ManiSkill's
    sim_backend where it is not physx_cpu.
    observe: observe without its worker count."""
    if stage == "source":
        return {"task": params.task, "backend": params.backend, "source": as_dict(params.source)}
    if stage == "observe":
        o = as_dict(params.observe)
        for key in _NOT_DATA["observe"]:
            del o[key]
        return {"observe": o}
    g = as_dict(params.generate)
    unused = ("num_demos",) if g["mode"] == "fixed_attempts" else ()
    unused += ("transit", "planner") if g["transit"] == "linear" else ()
    unused += ("num_envs",) if g["num_envs"] == 1 else ()  # one at a time: the bytes as before
    for key in _NOT_DATA["generate"] + unused:
        del g[key]
    out = {"generate": g, "pose_noise": as_dict(params.pose_noise)}
    if params.backend == "maniskill" and params.maniskill.sim_backend != "physx_cpu":
        out["maniskill"] = {"sim_backend": params.maniskill.sim_backend}
    return out


# the check stage's stamp: one constant line, on which every other stage of a pipeline
# depends, so that DVC runs the check first and its unchanged bytes re-run nothing
STAMP = "checked by mimicgen-pipe check before the pipeline's other stages\n"


@dataclass(frozen=True)
class CheckJob:
    """A pipeline's params file ``params_file``, found valid with the files it names (the
    check stage), and ``stamp``, the file that says so (None: none is written)."""

    params_file: Path
    stamp: Path | None


def write_stamp(job: CheckJob) -> None:
    """The job's stamp file, :data:`STAMP`, where it has one."""
    if job.stamp is not None:
        job.stamp.write_text(STAMP)
