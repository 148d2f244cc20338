"""The error every peer raises when it cannot be used."""


class PeerUnavailable(RuntimeError):
    """A peer renderer cannot be used here (or cannot render this scene); the message says
    why and how to fix it."""
