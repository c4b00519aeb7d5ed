"""Error types shown to users.

Every error a user can cause by bad input is a :class:`InputError`; the command line prints its
message on one line and exits with status 2. Everything else is a bug and keeps its traceback.
"""


class InputError(ValueError):
    """Bad input: an unknown robot, a malformed file, an impossible setting.

    The message names the file, row or field and says what was expected.
    """
