"""Policies trained elsewhere (a robomimic checkpoint, a LeRobot policy directory), rolled
out in our env by the evaluator like our own.

The policy runs in its framework's own Python (another virtualenv: the frameworks need
packages our simulators cannot share), in a server process (``_serve.py``, run by path)
that answers reset/act requests over its stdin/stdout; its wire format pickles nothing.
:class:`ExternalPolicy` is the evaluator's side: it starts the server, checks before any
rollout that our env provides every input the policy reads (:func:`check_hello`), and turns
each step's observation into the policy's input by the format's exporter's own function.

Policy formats are a registry (mimicgen_pipe.core.registry), one module per format named as
``--policy <format>:<path>`` names it. A format module runs in both Pythons, so it imports
nothing of mimicgen_pipe at its top; it defines

- ``DESCRIPTION``: what a policy of the format is, for error messages;
- ``why_not(path) -> str | None``: why ``path`` is not a policy of the format, looked at
  without loading it, or None;
- ``observation(obs, obs_keys) -> dict[str, np.ndarray]``: the policy's input, by the
  framework's names, from one step's observation (mimicgen_pipe.core.observations' keys, and
  ``<camera>_image`` for cameras), built as the format's exporter builds a frame
  (``obs_keys``: params' train.obs_keys, the keys the export wrote);
- ``image_key(camera) -> str``: the framework's name of a camera's images; optionally
  ``image_keys(camera) -> tuple[str, ...]``, every name a policy may read them by (a
  format whose exports renamed them), ``image_key``'s first;
- ``load(path, task)`` (server side, importing numpy, torch and the framework alone): the
  policy, with ``observations`` ({key: {"shape", "dtype"}}, as ``observation`` names them),
  ``action_dim``, ``meta`` (what the checkpoint says of its data: ``env_kwargs`` where it
  has them), ``reset(seed)`` and ``act(arrays) -> (action_dim,) array``;
- ``EPOCH_UNIT`` (``epoch`` or ``step``) and ``checkpoint_epoch(path) -> int | None``: how far
  its training had got when it saved the policy at ``path``, in that unit, read from the
  path as the framework names its checkpoints, None where the path does not say.

robomimic's own BC-RNN is trained here too, on our robomimic export, in the same Python
(:class:`TrainRobomimicJob`, the train_robomimic stage): ``_robomimic_train.py``, run by
path, runs robomimic's trainer on the config :func:`run_config` makes.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import json
import os
import re
import select
import subprocess
import tempfile
import time
import types
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from mimicgen_pipe.core.errors import InputError, StageError
from mimicgen_pipe.core.registry import choices, load
from mimicgen_pipe.core.taskspec import ARM_ACTION_DIM
from mimicgen_pipe.data.params import TrainProfile
from mimicgen_pipe.formats.external._serve import (
    LENGTH,
    OFFLINE,
    PROTOCOL,
    decode,
    encode,
    message_size,
)

SERVER = Path(__file__).resolve().parent / "_serve.py"
REPO = Path(__file__).resolve().parents[3]
# the check virtualenv that scripts/setup.sh makes, where robomimic and lerobot are installed
DEFAULT_PYTHON = REPO / ".venv-learners" / "bin" / "python"
HELLO_SECONDS = 600.0  # importing a framework and loading a policy, on a busy machine
ACT_SECONDS = 120.0
CLOSE_SECONDS = 10.0
STDERR_LINES = 8  # of the server's stderr, in the error when it fails


def format_module(fmt: str) -> types.ModuleType:
    """The module of policy format ``fmt``; InputError naming the formats for another."""
    known = choices("mimicgen_pipe.formats.external")
    if fmt not in known:
        raise InputError(f"policy format {fmt!r}: unknown (known: {', '.join(known)})")
    return load("mimicgen_pipe.formats.external", fmt)


@dataclass(frozen=True)
class PolicySpec:
    """A policy trained elsewhere and how to serve it. format: a module of this package.
    path: its checkpoint file or directory (absolute). python: the interpreter its
    framework is installed in. obs_keys: params' train.obs_keys (the keys the export wrote).
    task: the task sentence (mimicgen_pipe.formats.exporters.task_description)."""

    format: str
    path: str
    python: str
    obs_keys: tuple[str, ...]
    task: str

    @property
    def name(self) -> str:
        return f"{self.format}:{self.path}"

    def command(self) -> list[str]:
        """The server's command line."""
        return [self.python, str(SERVER), "--format", self.format, "--path", self.path,
                "--task", self.task]  # fmt: skip


def parse_policy(text: str) -> tuple[str, Path]:
    """``<format>:<path>`` (``--policy``) as (format, path), the path checked to be a policy
    of that format without loading it; InputError saying what was expected otherwise."""
    fmt, sep, path = text.partition(":")
    expected = "; ".join(
        f"{f}:<{format_module(f).DESCRIPTION}>" for f in choices("mimicgen_pipe.formats.external")
    )
    if not sep or not path:
        raise InputError(f"--policy {text!r}: expected <format>:<path>, i.e. {expected}")
    why = format_module(fmt).why_not(Path(path))
    if why:
        raise InputError(f"--policy {text!r}: {why}; expected {expected}")
    return fmt, Path(path)


def policy_digest(path: Path) -> str:
    """sha256 over a checkpoint file's bytes, or over a policy directory's files (their
    relative paths and bytes, in sorted order): which policy was rolled out."""
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        if path.is_dir():
            h.update(f.relative_to(path).as_posix().encode() + b"\0")
        with f.open("rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def check_python(python: str) -> str:
    """``python``, after an InputError when it is not an interpreter file (before any server
    starts)."""
    if not (os.path.isfile(python) and os.access(python, os.X_OK)):
        raise InputError(
            f"--python {python}: no such interpreter; give the Python that robomimic or "
            "lerobot is installed in (scripts/setup.sh makes the check virtualenv)"
        )
    return python


class ExternalPolicy:
    """A policy served by another process (:data:`SERVER` or any command speaking its wire
    format), acting in closed loop like mimicgen_pipe.learn.evaluation.ClosedLoopPolicy.
    ``observation`` maps one step's observation to the policy's input arrays (a format's
    ``observation``); ``name`` names the policy in errors. The server starts here and has
    said hello when this returns, in an environment that keeps the Hugging Face libraries
    offline (_serve.OFFLINE); a server that fails, ends or gives no answer in time
    (``hello_seconds`` to start, ``act_seconds`` per request) is one InputError with the
    last lines of its stderr, and is stopped."""

    def __init__(
        self,
        command: Sequence[str],
        observation: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]],
        name: str,
        hello_seconds: float = HELLO_SECONDS,
        act_seconds: float = ACT_SECONDS,
    ) -> None:
        self.name, self.observation, self.act_seconds = name, observation, act_seconds
        self._stderr = tempfile.TemporaryFile()
        try:
            self._proc = subprocess.Popen(
                list(command),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=self._stderr,
                bufsize=0,
                env=dict(os.environ, PYTHONUNBUFFERED="1", **OFFLINE),
            )
        except OSError as exc:
            self._stderr.close()
            raise InputError(f"{name}: cannot start its server {command[0]} ({exc})") from exc
        os.set_blocking(self._proc.stdin.fileno(), False)
        header, _ = self._receive("while loading the policy", hello_seconds)
        if header.get("op") != "hello" or header.get("protocol") != PROTOCOL:
            self._fail(f"said {header!r} where a hello of protocol {PROTOCOL} was expected")
        self.hello: dict[str, Any] = header
        self.keys: tuple[str, ...] = tuple(header["observations"])

    def reset(self, seed: int) -> None:
        self._send({"op": "reset", "seed": int(seed)}, {}, "reset")
        self._expect("ok", "reset")

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        inputs = self.observation(obs)
        self._send({"op": "act"}, {k: inputs[k] for k in self.keys}, "act")
        action = self._expect("action", "act")["action"]
        if action.shape != (self.hello["action_dim"],) or not np.isfinite(action).all():
            self._fail(f"answered an action of shape {action.shape} (or not finite)")
        return action.astype(np.float32)

    def close(self) -> None:
        """Ask the server to exit; stop it if it does not within CLOSE_SECONDS. Closing
        twice, or after an error, does nothing more."""
        if self._proc.poll() is None:
            try:
                self._write(encode({"op": "close"}), time.monotonic() + CLOSE_SECONDS)
                self._proc.stdin.close()
                self._proc.wait(CLOSE_SECONDS)
            except (OSError, subprocess.TimeoutExpired, InputError):
                self._proc.kill()
                self._proc.wait()
        self._release()

    def _release(self) -> None:
        for f in (self._proc.stdin, self._proc.stdout, self._stderr):
            f.close()

    def __enter__(self) -> ExternalPolicy:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- the wire ---------------------------------------------------------------------

    def _send(self, header: dict, arrays: dict[str, np.ndarray], what: str) -> None:
        try:
            self._write(encode(header, arrays), time.monotonic() + self.act_seconds)
        except BrokenPipeError:
            self._fail(f"ended during {what}")

    def _expect(self, op: str, what: str) -> dict[str, np.ndarray]:
        header, arrays = self._receive(f"during {what}", self.act_seconds)
        if header["op"] != op:
            self._fail(f"said {header!r} during {what}, where {op!r} was expected")
        return arrays

    def _receive(self, when: str, seconds: float) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        deadline = time.monotonic() + seconds
        head = self._read(LENGTH.size, deadline, when, seconds)
        try:
            size = message_size(head)
            header, arrays = decode(self._read(size, deadline, when, seconds))
        except ValueError as exc:
            self._fail(f"sent an unreadable message {when} ({exc})")
        if header["op"] == "error":  # its own word: its stderr's traceback adds nothing
            self._fail(f"failed {when}: {header.get('message')}", stderr=False)
        return header, arrays

    def _read(self, n: int, deadline: float, when: str, seconds: float) -> bytes:
        fd, buf = self._proc.stdout.fileno(), bytearray()
        while len(buf) < n:
            left = deadline - time.monotonic()
            if left <= 0:
                self._fail(f"gave no answer within {seconds:g} s {when}")
            if select.select([fd], [], [], left)[0]:
                chunk = os.read(fd, n - len(buf))
                if not chunk:
                    self._fail(f"ended {when}")
                buf += chunk
        return bytes(buf)

    def _write(self, data: bytes, deadline: float) -> None:
        fd, view = self._proc.stdin.fileno(), memoryview(data)
        while view:
            left = deadline - time.monotonic()
            if left <= 0:
                self._fail("read no request within its time")
            if select.select([], [fd], [], left)[1]:
                try:
                    view = view[os.write(fd, view) :]
                except BlockingIOError:
                    continue

    def _fail(self, what: str, stderr: bool = True) -> NoReturn:
        """Stop the server; raise InputError with its exit status and (``stderr``) the last
        lines of its stderr."""
        if self._proc.poll() is None:
            self._proc.kill()
        status = self._proc.wait()
        self._stderr.seek(0)
        lines = self._stderr.read().decode(errors="replace").strip().splitlines()
        tail = " | ".join(lines[-STDERR_LINES:]) if stderr else ""
        self._release()
        raise InputError(
            f"{self.name}: its policy server {what} (exit status {status})"
            + (f"; its stderr ends: {tail}" if tail else "")
        )


def policy_cameras(
    spec: PolicySpec, hello: Mapping[str, Any], known: Sequence[str]
) -> tuple[tuple[str, ...], tuple[int, int] | None]:
    """The cameras of ``known`` (the arm's, mimicgen_pipe.backends.<backend>.cameras) whose images
    the policy reads, and their (height, width) [px], None for none; InputError for images of
    several sizes (the rollouts picture every camera at one size)."""
    fmt, needed = format_module(spec.format), hello["observations"]
    names = getattr(fmt, "image_keys", lambda c: (fmt.image_key(c),))
    read = {c: [k for k in names(c) if k in needed] for c in known}
    cameras = tuple(c for c in known if read[c])
    sizes = {c: tuple(needed[read[c][0]]["shape"][:2]) for c in cameras}
    if len(set(sizes.values())) > 1:
        raise InputError(f"{spec.name}: reads images of several sizes {sizes}; expected one")
    return cameras, (next(iter(sizes.values())) if sizes else None)


def provided_inputs(
    fmt: str,
    obs_dims: Mapping[str, int],
    obs_keys: Sequence[str],
    cameras: Sequence[str] = (),
    size: tuple[int, int] | None = None,
) -> dict[str, tuple[tuple[int, ...], str]]:
    """What our env gives a policy of format ``fmt``: input name -> (shape, dtype), from an
    observation of the task's keys and widths (mimicgen_pipe.core.observations.observation_dims)
    and ``cameras``' images of ``size`` (height, width) through the format's
    ``observation``."""
    obs = {k: np.zeros(d, np.float32) for k, d in obs_dims.items()}
    obs |= {f"{c}_image": np.zeros((*size, 3), np.uint8) for c in cameras} if size else {}
    inputs = format_module(fmt).observation(obs, tuple(obs_keys))
    return {k: (tuple(v.shape), str(v.dtype)) for k, v in inputs.items()}


def check_hello(
    spec: PolicySpec,
    hello: Mapping[str, Any],
    provided: Mapping[str, tuple[tuple[int, ...], str]],
    env_kwargs: Mapping[str, str],
    cameras: Sequence[str],
    action_dim: int = ARM_ACTION_DIM,
) -> None:
    """InputError, before any rollout, for a policy our env cannot run: one naming every
    input it reads that ``provided`` lacks (images among them: the rollouts picture the
    arm's ``cameras`` alone), or of another shape; for an action size other than ours
    (``action_dim``: 7 per arm of the task); for
    checkpoint ``meta`` naming another back end, task or robot than ``env_kwargs``."""
    needed = hello["observations"]
    missing = [k for k in needed if k not in provided]
    if missing:
        images = [k for k in missing if len(needed[k]["shape"]) == 3]
        known = ", ".join(cameras) or "none"
        raise InputError(
            f"{spec.name}: reads observations our env does not provide: {', '.join(missing)}"
            + (
                f" ({', '.join(images)}: images of cameras it lacks; it has {known})"
                if images
                else ""
            )  # fmt: skip
            + f"; it provides {', '.join(provided)}"
        )
    wrong = {
        k: (tuple(v["shape"]), v["dtype"])
        for k, v in needed.items()
        if (tuple(v["shape"]), v["dtype"]) != provided[k]
    }
    if wrong:
        detail = ", ".join(f"{k} {s} {d} (ours: {provided[k][0]} {provided[k][1]})"
                           for k, (s, d) in wrong.items())  # fmt: skip
        raise InputError(
            f"{spec.name}: reads {detail}; train.obs_keys {list(spec.obs_keys)} gives ours"
        )
    if hello["action_dim"] != action_dim:
        raise InputError(
            f"{spec.name}: acts with {hello['action_dim']} numbers per step; our env takes "
            f"{action_dim} (dx, dy, dz, drx, dry, drz, gripper"
            + (
                f", for each of {action_dim // ARM_ACTION_DIM} arms)"
                if action_dim > ARM_ACTION_DIM
                else ")"
            )
        )
    theirs = (hello.get("meta") or {}).get("env_kwargs") or {}
    other = {k: theirs[k] for k in env_kwargs if k in theirs and theirs[k] != env_kwargs[k]}
    if other:
        raise InputError(
            f"{spec.name}: trained on data of {other} (its env_kwargs), evaluated with "
            f"{ {k: env_kwargs[k] for k in other} }"
        )


@dataclass(frozen=True)
class Probed:
    """What a policy reads, as its server said: ``observations`` ({key: {"shape",
    "dtype"}}), and of them the ``cameras`` whose images it reads, at ``size`` (height,
    width) [px], None for none."""

    observations: Mapping[str, Mapping[str, Any]]
    cameras: tuple[str, ...]
    size: tuple[int, int] | None


def probe(
    spec: PolicySpec,
    obs_dims: Mapping[str, int],
    env_kwargs: Mapping[str, str],
    known: Sequence[str],
    action_dim: int = ARM_ACTION_DIM,
) -> Probed:
    """Start the policy's server and check, before any rollout, that our env gives it every
    input (:func:`check_hello`; ``obs_dims``: the task's observation widths, ``known``: the
    arm's cameras) and takes its actions (``action_dim`` wide). Returns what it reads."""
    with start_policy(spec) as policy:
        hello = policy.hello
    cameras, size = policy_cameras(spec, hello, known)
    provided = provided_inputs(spec.format, obs_dims, spec.obs_keys, cameras, size)
    check_hello(spec, hello, provided, env_kwargs, known, action_dim)
    return Probed(hello["observations"], cameras, size)


def start_policy(spec: PolicySpec, **timeouts: float) -> ExternalPolicy:
    """A started server for ``spec``, with the format's observation."""
    observation = functools.partial(format_module(spec.format).observation, obs_keys=spec.obs_keys)
    return ExternalPolicy(spec.command(), observation, spec.name, **timeouts)


def load_external_policy(spec: PolicySpec, name: str) -> ExternalPolicy:
    """mimicgen_pipe.learn.evaluation's ``load_policy`` for ``spec`` (``name``: its name there)."""
    return start_policy(spec)


TRAINER = Path(__file__).resolve().parent / "_robomimic_train.py"  # run in robomimic's Python
# robomimic's log: "Train Epoch <N>" then that epoch's training statistics as a JSON object
EPOCH_LOG = re.compile(r"^Train Epoch (\d+)\n(\{\n.*?\n\})$", re.M | re.S)


@dataclass(frozen=True)
class TrainRobomimicJob:
    """One train_robomimic run, checked (mimicgen_pipe.stages.train_robomimic.resolve):
    robomimic's BC-RNN of the robomimic ``config`` (algo_name bc with an RNN:
    :func:`check_bc_rnn`), trained in ``python`` (robomimic's interpreter) on our robomimic
    export ``dataset`` of ``data`` (task ``task`` of back end ``backend``, arm ``robot``), at
    the size and schedule of our training profile ``profile`` (params train.profile
    ``profile_name``), one run of its first seed, a checkpoint every ``every_epochs`` epochs,
    observations as stored or ``normalize``d by robomimic. Written as the checkpoints ``out``
    (model_epoch_<N>.pth), the metrics JSON ``metrics_path`` and the loss per epoch ``plot``
    (CSV)."""

    task: str
    backend: str
    robot: str
    data: str
    profile_name: str
    profile: TrainProfile
    every_epochs: int
    normalize: bool
    dataset: Path
    config: Mapping[str, Any]
    python: str
    out: Path
    metrics_path: Path
    plot: Path


def check_bc_rnn(config: Mapping[str, Any]) -> None:
    """InputError unless ``config`` is one of robomimic's BC-RNN (algo_name bc, algo.rnn)."""
    if config.get("algo_name") != "bc" or not config.get("algo", {}).get("rnn"):
        raise InputError("config: expected robomimic's BC-RNN (algo_name bc, algo.rnn)")


def run_config(job: TrainRobomimicJob, output_dir: Path) -> dict[str, Any]:
    """The job's config with our profile's sizes and schedule, its first seed, a checkpoint
    every ``every_epochs`` epochs, the dataset and output folder; rollouts and validation
    off (robomimic cannot build our env, and normalises no validation data)."""
    c, prof = copy.deepcopy(dict(job.config)), job.profile
    e, t, a = c["experiment"], c["train"], c["algo"]
    e.update(name="run", validate=False, epoch_every_n_steps=prof.steps_per_epoch)
    e["save"] |= {"enabled": True, "every_n_epochs": job.every_epochs, "on_best_validation": False}
    e["rollout"] = {"enabled": False}
    e["logging"] = {"terminal_output_to_txt": True, "log_tb": False, "log_wandb": False}
    t.update(
        data=str(job.dataset.resolve()), output_dir=str(output_dir), seed=prof.seeds[0],
        num_epochs=prof.epochs, batch_size=prof.batch_size, seq_length=prof.seq_len,
        hdf5_normalize_obs=job.normalize, hdf5_filter_key="train", cuda=False,
    )  # fmt: skip
    a["rnn"] |= {"horizon": prof.seq_len, "hidden_dim": prof.hidden, "num_layers": prof.layers}
    a.setdefault("optim_params", {}).setdefault("policy", {})["learning_rate"] = {
        "initial": prof.lr, "decay_factor": 0.1, "epoch_schedule": [],
    }  # fmt: skip
    return c


def epoch_losses(log: str) -> list[tuple[int, float]]:
    """(epoch, mean training loss) of each epoch robomimic logged."""
    return [(int(n), float(json.loads(body)["Loss"])) for n, body in EPOCH_LOG.findall(log)]


def train_robomimic(job: TrainRobomimicJob, work: Path) -> tuple[Path, float]:
    """robomimic's training of ``job`` in the scratch folder ``work``, its output (each
    epoch's statistics, its progress bars) passed through: its run folder and wall time
    [s]; StageError when it fails."""
    path = work / "config.json"
    path.write_text(json.dumps(run_config(job, work / "runs"), indent=1))
    t0 = time.perf_counter()
    res = subprocess.run([job.python, str(TRAINER), "--config", str(path)], check=False)
    if res.returncode != 0:
        raise StageError(
            f"robomimic's training failed (exit {res.returncode}; its output is above)"
        )
    (run,) = (work / "runs/run").iterdir()  # robomimic's <time stamp> folder
    return run, time.perf_counter() - t0
