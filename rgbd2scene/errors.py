"""The one exception type for bad user input (the CLI prints it as ``error: ...`` and exits 2)."""


class UserError(Exception):
    """A problem with the user's input or output location, explained in one line.

    The message names the file (or option) and the problem; the CLI prints ``error: <message>``
    on stderr and exits with status 2, without a traceback.
    """


class RenderError(RuntimeError):
    """The Blender worker failed (crash, Blender error); the message holds the tail of its log.

    Not the user's fault: the CLI prints ``error: ...`` and exits with status 1.
    """
