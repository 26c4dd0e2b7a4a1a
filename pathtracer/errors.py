"""The project's own errors: one line a user can act on, naming the file, the element and the problem."""

from __future__ import annotations


class PathtracerError(Exception):
    """Base of every error the renderer raises on purpose (the CLI prints these as one line, exit status 2)."""


class SceneError(PathtracerError):
    """A scene file or dict that cannot be loaded: names the source, the element and what is supported."""

    def __init__(self, source: str, element: str, problem: str):
        self.source, self.element, self.problem = source, element, problem
        where = f"{source}: {element}" if element else source
        super().__init__(f"{where}: {problem}")


class RenderError(PathtracerError):
    """Bad render options (spp <= 0, unknown device, ...)."""


class ImageIOError(PathtracerError):
    """An image that cannot be written or read."""
