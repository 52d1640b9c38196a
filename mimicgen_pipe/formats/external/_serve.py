"""The policy server: one policy trained elsewhere answering reset/act requests on its
stdin/stdout. Run by path under the framework's own Python, where mimicgen_pipe is not
installed::

    <python> mimicgen_pipe/formats/external/_serve.py --format robomimic --path model.pth --task
    "..."

It imports numpy, the format's module of this folder (by path) and, through it, torch and
the framework: nothing else, and nothing it reads or writes is ever unpickled.

Wire format, both ways: a message is an 8-byte little-endian length, then that many bytes of
an ``.npz`` archive (numpy.savez, read with allow_pickle=False) whose entry ``header`` is a
JSON object (a 0-d unicode array) and whose other entries are arrays.

- server, once at start: ``{"op": "hello", "protocol": 1, "format", "observations":
  {key: {"shape": [...], "dtype": "float32" | "uint8"}}, "action_dim", "meta"}`` (what the
  policy reads, as the client sends it; ``meta``: what the checkpoint says of its data), or
  ``{"op": "error", "message"}`` when the policy cannot be loaded;
- client ``{"op": "reset", "seed"}``: a new episode, the policy's random state seeded with
  ``seed``; answer ``{"op": "ok"}``;
- client ``{"op": "act"}`` with one array per observation key: answer ``{"op": "action"}``
  with ``action``, (action_dim,) float32;
- client ``{"op": "close"}``, or the end of its input: the server exits (status 0).

A request that fails is answered ``{"op": "error", "message"}`` and the server exits with
status 1. Whatever the framework prints goes to stderr: stdout carries messages only.
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import json
import os
import signal
import struct
import sys
import traceback
from pathlib import Path
from typing import IO, Any, BinaryIO

HERE = Path(__file__).resolve().parent
# Run by path, Python puts this folder first on sys.path, where robomimic.py and lerobot.py
# would hide the frameworks of the same names.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]

import numpy as np  # noqa: E402

PROTOCOL = 1
LENGTH = struct.Struct("<Q")
HEADER = "header"
# the Hugging Face libraries' offline switches, set in the server's environment: a policy
# is its own files, so nothing it loads may come from the Hub (what a format refuses or
# turns off before loading is the check; these are a second wall)
OFFLINE = {"HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}
# a message is one step's observation or action: far below this (two 84x84 images: 42 kB);
# a larger length is garbage on the stream, refused before anything is allocated for it
MAX_MESSAGE = 256 << 20


def encode(header: dict[str, Any], arrays: dict[str, np.ndarray] | None = None) -> bytes:
    """One message: its length, then the npz of ``header`` (as JSON) and ``arrays``."""
    buf = io.BytesIO()
    np.savez(buf, **{HEADER: np.array(json.dumps(header))}, **(arrays or {}))
    payload = buf.getvalue()
    return LENGTH.pack(len(payload)) + payload


def decode(payload: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(header, arrays) of one message's payload (without its length); ValueError for bytes
    that are not such an npz."""
    with np.load(io.BytesIO(payload), allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    header = json.loads(str(arrays.pop(HEADER)))
    if not isinstance(header, dict) or not isinstance(header.get("op"), str):
        raise ValueError(f"message header {header!r}: expected a JSON object with an 'op'")
    return header, arrays


def message_size(head: bytes) -> int:
    """The payload size an 8-byte length announces; ValueError past :data:`MAX_MESSAGE`."""
    (size,) = LENGTH.unpack(head)
    if size > MAX_MESSAGE:
        raise ValueError(
            f"a message of {size} bytes announced, over the {MAX_MESSAGE >> 20} MiB limit: "
            "not this protocol's stream"
        )
    return size


def read_message(stream: BinaryIO) -> tuple[dict[str, Any], dict[str, np.ndarray]] | None:
    """The next message of a blocking stream, None at its end."""
    head = stream.read(LENGTH.size)
    if not head:
        return None
    if len(head) < LENGTH.size:
        raise EOFError("input ended inside a message's length")
    size = message_size(head)
    payload = stream.read(size)
    if len(payload) < size:
        raise EOFError(f"input ended inside a message ({len(payload)} of {size} bytes)")
    return decode(payload)


def load_format(name: str):
    """The module of policy format ``name`` (this folder's ``<name>.py``), loaded by path."""
    path = HERE / f"{name}.py"
    if name.startswith("_") or not path.is_file():
        known = sorted(p.stem for p in HERE.glob("*.py") if not p.stem.startswith("_"))
        raise ValueError(f"policy format {name!r}: unknown (known: {', '.join(known)})")
    spec = importlib.util.spec_from_file_location(f"policy_format_{name}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def serve(load, fmt: str, messages_in: BinaryIO, messages_out: IO[bytes]) -> int:
    """Load the policy (``load()``, a format's ``Served``), say hello, then answer requests
    until close or the end of input. Returns the exit status."""

    def send(header: dict[str, Any], arrays: dict[str, np.ndarray] | None = None) -> None:
        messages_out.write(encode(header, arrays))
        messages_out.flush()

    def fail(what: str, exc: BaseException) -> int:
        traceback.print_exc(file=sys.stderr)
        send({"op": "error", "message": f"{what}: {type(exc).__name__}: {exc}"})
        return 1

    try:
        policy = load()
    except Exception as exc:  # the client reports it as the reason the policy is refused
        return fail("cannot load the policy", exc)
    send(
        {
            "op": "hello",
            "protocol": PROTOCOL,
            "format": fmt,
            "observations": policy.observations,
            "action_dim": int(policy.action_dim),
            "meta": policy.meta,
        }
    )
    while True:
        try:
            message = read_message(messages_in)
        except (EOFError, ValueError) as exc:
            return fail("unreadable request", exc)
        if message is None:
            return 0
        header, arrays = message
        op = header["op"]
        try:
            if op == "close":
                return 0
            if op == "reset":
                policy.reset(int(header["seed"]))
                send({"op": "ok"})
            elif op == "act":
                action = np.asarray(policy.act(arrays), np.float32).reshape(-1)
                send({"op": "action"}, {"action": action})
            else:
                raise ValueError(f"unknown request {op!r}")
        except Exception as exc:
            return fail(f"{op} failed", exc)


def main(argv: list[str] | None = None, load_policy=None) -> int:
    """The server's command line; ``load_policy(path, task)`` replaces the format's ``load``
    (a stand-in policy)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--format", required=True, help="policy format: a module of this folder")
    p.add_argument("--path", required=True, help="the checkpoint file or policy directory")
    p.add_argument("--task", default="", help="the task sentence (LeRobot's task string)")
    args = p.parse_args(argv)
    os.environ.update(OFFLINE)  # also when run by hand; before any framework is imported
    # the client alone decides what a Ctrl-C in its terminal stops; it then closes our input
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # messages go to the real stdout; everything printed (Python or C) goes to stderr
    messages_out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    messages_in = sys.stdin.buffer

    def load():
        return (load_policy or load_format(args.format).load)(args.path, args.task)

    return serve(load, args.format, messages_in, messages_out)


if __name__ == "__main__":
    sys.exit(main())
