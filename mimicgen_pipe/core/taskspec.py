"""Task specifications: the ordered object-centric subtasks of each arm, the constraints
between two arms' subtasks, each reset variant's distribution, and what the task stands for
in the paper. Free of simulator imports: a task file under
``mimicgen_pipe/tasks/<backend>/`` builds one of these."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.observations import observation_dims, observation_keys

ARM_ACTION_DIM = 7  # one arm's action: delta position (3), delta rotation (3), gripper (1)

ARM = "arm"  # the arm of a one-arm task's subtasks


def arm_key(key: str, arm: str) -> str:
    """The name of an arm's step array ``key`` (eef_pose, target_pose, gripper): the key
    itself for a one-arm task's arm, ``<key>/<arm>`` for one of several."""
    return key if arm == ARM else f"{key}/{arm}"


@dataclass(frozen=True)
class SubtaskSpec:
    """One object-centric subtask (paper 3.1, J.2).

    reference_object: the object the subtask's motion is relative to.
    term_signal: name of the boolean signal whose first 0->1 transition (after the previous
        subtask's end) ends this subtask in a source demo; None for the final subtask, which
        ends with the demo.
    term_offset_range: (lo, hi) steps, inclusive, added to the detected end; sampled per
        generation attempt as in the reference implementation.
    noise_free_radius: [m] the subtask's steps whose target position is within this
        distance of the reference object's position (world frame, as the generator observes
        it) get no action noise (paper M.4): the last centimetres of a tight insertion, for
        one. None: action noise on every step.
    arm: the arm that carries it out. Each arm has its own ordered subtasks, the task's
        subtasks of that arm in order; a one-arm task leaves it at ARM.
    """

    name: str
    reference_object: str
    term_signal: str | None
    term_offset_range: tuple[int, int] = (0, 0)
    noise_free_radius: float | None = None
    arm: str = ARM


@dataclass(frozen=True)
class SubtaskConstraint:
    """A constraint between subtasks of two arms, each named (arm, subtask name).

    sequential: ``second`` starts only once ``first`` has ended (one arm waits for the
        other, e.g. one holds a box the other then places into).
    coordinated: ``first`` and ``second`` start together and move as one: both segments
        come from the same source demo, are transformed by the pose of the one reference
        object both subtasks name, and are executed step-aligned (e.g. both arms lifting one
        tray).
    """

    kind: Literal["sequential", "coordinated"]
    first: tuple[str, str]
    second: tuple[str, str]


@dataclass(frozen=True)
class ObjectBounds:
    """Reset bounds of one object: x, y [m] in the world frame, yaw [rad] about world z."""

    x: tuple[float, float]
    y: tuple[float, float]
    yaw: tuple[float, float]


@dataclass(frozen=True)
class ResetVariant:
    """One reset distribution (paper D0/D1/D2): every object's initial pose.

    bounds: object name -> the box its (x, y, yaw) is drawn from, uniformly; coverage bins
        the same box.
    min_distance: [m] objects are redrawn while two centres are closer than this.
    max_reach: [m] objects are redrawn while farther than this horizontally from the robot
        base (the arm's top-down reach); None: no cut.
    native: the simulator task's own reset distribution (ManiSkill's D0); ``bounds`` then
        state the box that distribution covers, for coverage, and nothing is redrawn.
    """

    bounds: Mapping[str, ObjectBounds]
    min_distance: float = 0.0
    max_reach: float | None = None
    native: bool = False


@dataclass(frozen=True)
class TaskSpec:
    """A task as the generator sees it.

    objects: names of the objects whose poses are recorded.
    subtasks: ordered subtasks of each arm (SubtaskSpec.arm); of every arm's, all but the
        last have a term signal.
    reset_variants: variant name (D0, D1, ...) -> its reset distribution.
    horizon: maximum episode length [control steps] for policy evaluation.
    paper_task: the paper's task this one stands for (its name in the paper's tables).
    obs_keys: the policy's default low-dim observation (mimicgen_pipe.core.observations); empty:
        every key the task provides.
    max_action_noise: the largest action-noise sigma (paper M.4) this task's tolerances
        take; generation uses no more, whatever it is asked for (the paper, too, sets its
        generation knobs per task, M.6). None: no cap.
    constraints: between subtasks of two arms (SubtaskConstraint); none for one arm.
    version: the task's behaviour version, raised by one whenever what its file does changes
        (scene, reset variants, signals, success test, demonstrator); stores and policies
        record it (:func:`version_record`), and generate and train refuse data of another.
    """

    name: str
    objects: tuple[str, ...]
    subtasks: tuple[SubtaskSpec, ...]
    reset_variants: Mapping[str, ResetVariant]
    horizon: int
    paper_task: str = ""
    obs_keys: tuple[str, ...] = ()
    max_action_noise: float | None = None
    constraints: tuple[SubtaskConstraint, ...] = ()
    version: int = 1

    def action_noise(self, sigma: float) -> float:
        """The action-noise sigma generation uses when asked for ``sigma``."""
        return sigma if self.max_action_noise is None else min(sigma, self.max_action_noise)

    @property
    def arms(self) -> tuple[str, ...]:
        """The arms, in the order their first subtask appears."""
        return tuple(dict.fromkeys(s.arm for s in self.subtasks))

    def arm_subtasks(self, arm: str) -> tuple[SubtaskSpec, ...]:
        """``arm``'s subtasks, in order."""
        return tuple(s for s in self.subtasks if s.arm == arm)

    def arm_indices(self, arm: str) -> tuple[int, ...]:
        """The indices in ``subtasks`` of ``arm``'s subtasks, in order."""
        return tuple(i for i, s in enumerate(self.subtasks) if s.arm == arm)

    @property
    def ending_subtasks(self) -> tuple[int, ...]:
        """The indices of the subtasks with a term signal (every arm's but its last): the
        columns of a parsed store's subtask ends, in this order."""
        return tuple(i for i, s in enumerate(self.subtasks) if s.term_signal is not None)

    def term_columns(self, arm: str) -> list[int]:
        """The columns of a parsed store's subtask ends (``ending_subtasks``) that are
        ``arm``'s, in the arm's order."""
        ending = self.ending_subtasks
        return [ending.index(i) for i in self.arm_indices(arm)[:-1]]

    @property
    def variants(self) -> tuple[str, ...]:
        return tuple(self.reset_variants)

    @property
    def provided_obs_keys(self) -> tuple[str, ...]:
        """Every observation key the generator records for this task."""
        return observation_keys(self.objects, self.several_arms)

    @property
    def observation_dims(self) -> dict[str, int]:
        """Width of every observation key the generator records for this task."""
        return observation_dims(self.objects, self.several_arms)

    @property
    def action_dim(self) -> int:
        """Entries of one action: ARM_ACTION_DIM per arm, in arm order."""
        return ARM_ACTION_DIM * len(self.arms)

    @property
    def several_arms(self) -> tuple[str, ...]:
        """The arms of a task of several; empty for a one-arm task (whose step arrays and
        observation keys carry no arm name)."""
        return self.arms if len(self.arms) > 1 else ()

    @property
    def default_obs_keys(self) -> tuple[str, ...]:
        return self.obs_keys or self.provided_obs_keys

    @property
    def signals(self) -> tuple[str, ...]:
        """The term signals the subtasks read."""
        return tuple(s.term_signal for s in self.subtasks if s.term_signal is not None)

    def __post_init__(self) -> None:
        if not self.subtasks:
            raise ValueError(f"task {self.name}: no subtasks")
        for arm in self.arms:
            subtasks = self.arm_subtasks(arm)
            names = [s.name for s in subtasks]
            if len(set(names)) < len(names):
                raise ValueError(f"task {self.name}: arm {arm} has two subtasks of one name")
            for sub in subtasks[:-1]:
                if sub.term_signal is None:
                    raise ValueError(f"task {self.name}: subtask {sub.name} needs a term signal")
            if subtasks[-1].term_signal is not None:
                raise ValueError(
                    f"task {self.name}: the final subtask{_of(arm)} ends with the demo"
                )
        check_constraints(self)
        for sub in self.subtasks:
            if sub.reference_object not in self.objects:
                raise ValueError(f"task {self.name}: unknown object {sub.reference_object}")
            lo, hi = sub.term_offset_range
            if not 0 <= lo <= hi:
                raise ValueError(f"task {self.name}: bad offset range {sub.term_offset_range}")
            if sub.noise_free_radius is not None and not sub.noise_free_radius >= 0:
                raise ValueError(
                    f"task {self.name}: subtask {sub.name}'s noise_free_radius "
                    f"{sub.noise_free_radius} is not a distance >= 0 [m]"
                )
        for name, variant in self.reset_variants.items():
            missing = [o for o in self.objects if o not in variant.bounds]
            if missing:
                raise ValueError(f"task {self.name}: variant {name} lacks bounds of {missing}")
        if self.max_action_noise is not None and not self.max_action_noise >= 0:
            raise ValueError(f"task {self.name}: max_action_noise {self.max_action_noise} < 0")
        unknown = [k for k in self.obs_keys if k not in self.provided_obs_keys]
        if unknown:
            raise ValueError(f"task {self.name}: obs_keys {unknown} are not recorded")


def _of(arm: str) -> str:
    return "" if arm == ARM else f" of arm {arm}"


def check_constraints(spec: TaskSpec) -> None:
    """ValueError unless ``spec``'s constraints can all hold: each names two subtasks that
    exist, of two different arms; coordinated subtasks share their reference object; and no
    cycle of constraints and arms' own orders makes a subtask wait for itself."""
    events: dict[tuple[str, str, str], tuple[str, str, str]] = {}  # union-find of events

    def root(e: tuple[str, str, str]) -> tuple[str, str, str]:
        while events.get(e, e) != e:
            e = events[e]
        return e

    known = {(s.arm, s.name): s for s in spec.subtasks}
    for c in spec.constraints:
        for arm, name in (c.first, c.second):
            if arm not in spec.arms:
                raise ValueError(
                    f"task {spec.name}: {c.kind} constraint {c.first} -> {c.second}: no arm "
                    f"{arm!r} (arms: {', '.join(spec.arms)})"
                )
            if (arm, name) not in known:
                have = ", ".join(s.name for s in spec.arm_subtasks(arm))
                raise ValueError(
                    f"task {spec.name}: {c.kind} constraint {c.first} -> {c.second}: arm "
                    f"{arm} has no subtask {name!r} (its subtasks: {have})"
                )
        if c.first[0] == c.second[0]:
            raise ValueError(
                f"task {spec.name}: {c.kind} constraint {c.first} -> {c.second}: one arm's "
                "subtasks already run in order; a constraint is between two arms"
            )
        if c.kind == "coordinated":
            a, b = known[c.first], known[c.second]
            if a.reference_object != b.reference_object:
                raise ValueError(
                    f"task {spec.name}: coordinated subtasks {c.first} and {c.second} move "
                    f"relative to one object; they name {a.reference_object} and "
                    f"{b.reference_object}"
                )
            for event in ("start", "end"):  # they start together and end together
                events[root((event, *c.first))] = root((event, *c.second))
    # an edge u -> v: event u comes before event v
    edges: dict[tuple[str, str, str], set[tuple[str, str, str]]] = {}

    def edge(u: tuple[str, str, str], v: tuple[str, str, str]) -> None:
        edges.setdefault(root(u), set()).add(root(v))

    for arm in spec.arms:
        subtasks = spec.arm_subtasks(arm)
        for i, s in enumerate(subtasks):
            edge(("start", arm, s.name), ("end", arm, s.name))
            if i + 1 < len(subtasks):
                edge(("end", arm, s.name), ("start", arm, subtasks[i + 1].name))
    for c in spec.constraints:
        if c.kind == "sequential":
            edge(("end", *c.first), ("start", *c.second))
    state: dict[tuple[str, str, str], int] = {}  # 1: on the path, 2: done

    def visit(u: tuple[str, str, str], path: list) -> None:
        state[u] = 1
        for v in edges.get(u, ()):
            if state.get(v) == 1:
                cycle = path[path.index(v) :] + [v] if v in path else [u, v]
                steps = " -> ".join(f"{e[0]} of {e[1]}/{e[2]}" for e in cycle)
                raise ValueError(f"task {spec.name}: the constraints make a cycle: {steps}")
            if v not in state:
                visit(v, path + [v])
        state[u] = 2

    for u in list(edges):
        if u not in state:
            visit(u, [u])


def version_record(spec: TaskSpec) -> dict[str, int]:
    """What a store, a checkpoint or a metrics file records of ``spec``'s version:
    ``{"task_version": N}``, and nothing at version 1, which a record without one means (so
    that what was made before versions keeps its bytes)."""
    return {} if spec.version == 1 else {"task_version": spec.version}


def check_task_version(attrs: Mapping[str, Any], spec: TaskSpec, where: str) -> None:
    """InputError naming ``where`` when the data whose attributes are ``attrs`` was made with
    another version of ``spec``'s task than its file has now."""
    made = attrs.get("task_version", 1)
    if made != spec.version:
        raise InputError(
            f"{where}: made with version {made} of task {spec.name}, whose file is at version "
            f"{spec.version}; re-run the stages that made it"
        )
