"""The official MimicGen code's timing, for a benchmark to print beside ours: runs
benchmarks/official_mimicgen.py in its own venv (.venv-official, built by
scripts/official_mimicgen_venv.sh), which the project never imports. Standard library only."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DRIVER = Path(__file__).resolve().with_name("official_mimicgen.py")
VENV_ENV = "MIMICGEN_OFFICIAL_VENV"
DEFAULT_VENV = ROOT / ".venv-official"
NOT_MEASURED = (
    "official MimicGen not measured: no venv at .venv-official "
    "(bash scripts/official_mimicgen_venv.sh builds it; "
    f"{VENV_ENV} points at another)"
)


class OfficialRunError(RuntimeError):
    """The official driver failed; the message ends with its stderr's tail."""


def official_venv() -> Path | None:
    """The official venv ($MIMICGEN_OFFICIAL_VENV, else .venv-official at the repo root), or
    None where it has no python."""
    venv = Path(os.environ.get(VENV_ENV) or DEFAULT_VENV)
    return venv if (venv / "bin" / "python").exists() else None


def run_official(
    attempts: int, seed: int, venv: Path, blocks: int = 1, timeout: float | None = None
) -> dict:
    """Times ``attempts`` official Stack D0 generate attempts (in ``blocks`` blocks, each on a
    rebuilt env) and returns the driver's JSON: attempts, successes, seconds, s_per_attempt,
    steps_per_attempt, ms_per_step, s_per_reset, versions. The first run also records the
    cached source demos, outside the timing."""
    cmd = [
        str(Path(venv) / "bin" / "python"),
        str(DRIVER),
        "--attempts",
        str(attempts),
        "--blocks",
        str(blocks),
        "--seed",
        str(seed),
        "--json",
    ]
    # the venv's python alone: none of the caller's paths or venv leak into it
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    try:
        proc = subprocess.run(
            cmd, capture_output=True, text=True, env=env, cwd=ROOT, timeout=timeout
        )
    except subprocess.TimeoutExpired as e:
        raise OfficialRunError(f"official MimicGen driver ran past {timeout} s") from e
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        tail = "\n".join(proc.stderr.strip().splitlines()[-20:])
        raise OfficialRunError(
            f"official MimicGen driver failed (exit {proc.returncode}): {' '.join(cmd)}\n{tail}"
        )
    try:
        return json.loads(lines[-1])
    except json.JSONDecodeError as e:
        raise OfficialRunError(f"official MimicGen driver printed no JSON: {lines[-1]!r}") from e
