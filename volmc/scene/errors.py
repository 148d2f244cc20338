"""The one error type for bad input: it carries the file and the key it is about."""


class VolmcError(Exception):
    """Bad input to volmc: a scene, grid or command-line value, or a Python API argument.

    ``str(err)`` is the one-line message ``<file>: <key>: <what is wrong>`` that the CLI
    prints after ``volmc: error: `` before exiting with status 2. ``file`` is the scene or
    grid file (``"command line"`` for a flag, ``"<dict>"`` or the name given for a scene
    built in Python, the function's name for an API argument such as ``volmc.render()``),
    ``key`` the dotted scene key or argument name ("" when the whole file is at fault), and
    ``message`` what is wrong. Exported as ``volmc.VolmcError``.
    """

    def __init__(self, file, key, message):
        self.file = str(file)
        self.key = key
        self.message = message
        text = f"{self.file}: {key}: {message}" if key else f"{self.file}: {message}"
        super().__init__(_one_line(text))

    def __reduce__(self):
        # Pickled as its parts (a Dask worker's error reaches the client this way): the
        # default, from the one-line text alone, cannot call __init__ again.
        return self.__class__, (self.file, self.key, self.message)


class VolmcWarning(UserWarning):
    """A render finished, but a guard fired (lookups above the majorant, walks cut by
    render.max_steps, dropped samples): the image may be biased. ``volmc.render`` issues one
    per guard with ``warnings.warn``, where ``volmc render`` prints ``volmc: warning: ``
    lines. Exported as ``volmc.VolmcWarning``."""


class SceneError(VolmcError):
    """Bad scene, grid or command-line value (every error volmc raises for bad input is one;
    a subclass of VolmcError, so ``except VolmcError`` catches it too)."""


def _one_line(text):
    """Escape line breaks and other non-printable characters (a key or file name may hold
    them), so the message stays one line."""
    return "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in text)
