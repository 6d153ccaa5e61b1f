"""The one exception type for bad input that the CLI reports as a one-line error."""


class InputError(ValueError):
    """Bad input from the user: a missing or malformed file, an impossible setting.

    The message must be one line that names the problem (file and line number where there
    is one); the CLI prints it as ``jaxvo: error: <message>`` and exits with status 2.
    """
