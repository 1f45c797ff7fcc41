"""Exceptions shared by the pose-graph modules (kept apart so that none imports another for them)."""


class PoseGraphError(Exception):
    """A user-facing problem (bad file, unknown backend, ...): one clear line."""


class InitializationError(PoseGraphError):
    """An initializer cannot run on this graph; the message is the one-line reason."""
