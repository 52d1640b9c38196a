"""The one error type the pipeline raises for bad input (files, keys, params)."""


class InputError(Exception):
    """Bad input, detected before any work: the message names the file/key and what was
    expected. The command-line entry point prints it on one line and exits with status 2."""
