"""The one error type for bad input: it carries the file and the key it is about."""


class SceneError(Exception):
    """Bad scene, grid or command-line value.

    ``str(err)`` is the one-line message ``<file>: <key>: <what is wrong>`` that the CLI
    prints after ``volmc: error: `` before exiting with status 2.
    """

    def __init__(self, file, key, message):
        self.file = str(file)
        self.key = key
        self.message = message
        text = f"{self.file}: {key}: {message}" if key else f"{self.file}: {message}"
        super().__init__(_one_line(text))


def _one_line(text):
    """Escape line breaks and other non-printable characters (a key or file name may hold
    them), so the message stays one line."""
    return "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in text)
