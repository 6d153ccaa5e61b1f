"""The one exception type for bad input that the CLI reports as a one-line error, and the
checks of input that several modules share."""

import operator
import sys

# The largest seed: JAX's default keys keep the low 32 bits of a seed (2**32 runs as 0) and
# NumPy's generators take no negative seed, so seeds are 0 .. 2**32 - 1 everywhere.
MAX_SEED = 2**32 - 1


class InputError(ValueError):
    """Bad input from the user: a missing or malformed file, an impossible setting.

    The message must be one line that names the problem (file and line number where there
    is one); the CLI prints it as ``jaxvo: error: <message>`` and exits with status 2.
    """


def warn(message: str) -> None:
    """A warning the user should read: one line ``jaxvo: warning: <message>`` on standard
    error, as the CLI prints its errors; the run goes on."""
    print(f"jaxvo: warning: {message}", file=sys.stderr)


def check_seed(seed: int, *, name: str = "seed") -> int:
    """A seed checked to be a whole number from 0 to :data:`MAX_SEED`.

    Args:
      seed: a Python or NumPy integer.
      name: what to call it in the message (e.g. ``--seed``).
    Returns:
      the seed, a Python int.
    Raises:
      InputError: another type or value.
    """
    try:
        value = operator.index(seed)  # Python and NumPy integers, not floats
    except TypeError:
        value = None
    if value is None or not 0 <= value <= MAX_SEED:
        raise InputError(f"{name} must be a whole number from 0 to {MAX_SEED} (2**32 - 1), "
                         f"got {seed!r}")
    return value
