"""A stand-in policy behind the policy server's own loop
(mimicgen_pipe.formats.external._serve.main), for the tests: it runs under this virtualenv's Python,
with no framework. Its ``--path`` is a JSON file: ``observations`` and ``action_dim`` (what its
hello announces), ``meta``, and how it misbehaves: ``fail_load`` (a message), ``exit_at`` /
``hang_at`` (the act call, counted from 1 over the server's life, at which it exits with status 3 /
sleeps). ``log``: a file each server appends its pid to when it starts. ``report_env``: names of
environment variables whose values at the process's start (as its client set them) its hello's
``meta["env"]`` gives.

Its action: action[i] = the sum of the i-th observation (keys in announced order, cycled),
plus normal noise of scale 0.01 drawn from a generator seeded at each reset."""

from __future__ import annotations

import json
import os
import sys
import time

import numpy as np

from mimicgen_pipe.formats.external import _serve

STARTED_WITH = dict(os.environ)  # before _serve.main sets anything


class StandIn:
    def __init__(self, path: str, task: str) -> None:
        config = json.loads(open(path).read())
        print(f"stand-in for {task!r}: loading")  # chatter that must not reach the messages
        if config.get("fail_load"):
            raise RuntimeError(config["fail_load"])
        if config.get("log"):
            with open(config["log"], "a") as f:
                f.write(f"{os.getpid()}\n")
        self.config = config
        self.observations = config["observations"]
        self.action_dim = config.get("action_dim", 7)
        self.meta = config.get("meta", {})
        if config.get("report_env"):
            self.meta["env"] = {k: STARTED_WITH.get(k) for k in config["report_env"]}
        self.calls = 0
        self.rng = np.random.default_rng(0)

    def reset(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, arrays: dict[str, np.ndarray]) -> np.ndarray:
        self.calls += 1
        if self.calls == self.config.get("exit_at"):
            print("stand-in: giving up", file=sys.stderr, flush=True)
            os._exit(3)
        if self.calls == self.config.get("hang_at"):
            time.sleep(3600)
        for key, want in self.observations.items():
            x = arrays[key]
            if list(x.shape) != want["shape"] or str(x.dtype) != want["dtype"]:
                raise ValueError(f"{key}: got {x.dtype} {x.shape}, announced {want}")
        sums = [float(arrays[k].sum()) for k in self.observations]
        action = np.array([sums[i % len(sums)] for i in range(self.action_dim)])
        return action + 0.01 * self.rng.normal(size=self.action_dim)


if __name__ == "__main__":
    sys.exit(_serve.main(load_policy=StandIn))
