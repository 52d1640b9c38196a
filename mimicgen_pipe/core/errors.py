"""The one error type the pipeline raises for bad input (files, keys, params)."""


class InputError(Exception):
    """Bad input, detected before any work: the message names the file/key and what was
    expected. The command-line entry point prints it on one line and exits with status 2."""


class StageError(Exception):
    """A failure outside the user's input that the stage can say in one line (a cluster
    that went away): the entry point prints it on one line and exits with status 1."""


LINE_LIMIT = 1000


def one_line(message: str, limit: int = LINE_LIMIT) -> str:
    """``message`` on one line of at most ``limit`` characters: newlines become " | ", and a
    longer message keeps its start and end around what was cut, with how much."""
    text = " | ".join(line for line in message.splitlines() if line.strip())
    if len(text) <= limit:
        return text
    keep = limit - 40  # the marker below takes at most 40 characters
    head = keep * 2 // 3
    cut = f" [... {len(text) - keep} characters cut ...] "
    return text[:head] + cut + text[len(text) - (keep - head) :]
