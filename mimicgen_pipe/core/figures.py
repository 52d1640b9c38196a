"""What every figure the project draws shares: importing matplotlib without its noise."""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Iterator


@contextlib.contextmanager
def quiet_matplotlib_import() -> Iterator[None]:
    """Import matplotlib inside this block: the deprecation warnings its import raises are
    silenced (matplotlib 3.9 still calls pyparsing's pre-3.3 names), nothing else."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=DeprecationWarning, module="pyparsing")
        warnings.filterwarnings("ignore", message=".*deprecated - use", category=UserWarning)
        yield
