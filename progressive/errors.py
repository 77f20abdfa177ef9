"""Errors a user can cause: the CLI turns each into one line and exit status 2."""


class ProgressiveError(Exception):
    """Any failure caused by input (files, options, cameras) rather than a bug."""


class InputError(ProgressiveError):
    """A file that cannot be read as a point cloud."""


class GLCapabilityError(ProgressiveError):
    """The OpenGL implementation lacks something the renderer needs."""
