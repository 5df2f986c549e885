"""Errors raised for bad input. Each message names the file (when there is one) and the problem."""

from __future__ import annotations

from pathlib import Path

__all__ = ["Clutt3rError", "SceneError", "SceneFileError", "MissingDependencyError"]


class Clutt3rError(Exception):
    """Base class of every error this package raises on purpose."""


class SceneError(Clutt3rError, ValueError):
    """A scene, view, camera or mask is inconsistent (wrong shape, non-rigid pose, ...)."""


class SceneFileError(SceneError):
    """A file of a scene on disk is missing, unreadable, or disagrees with the rest of the scene."""

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")

    def __reduce__(self):  # pickle (a worker process's error reaching the caller) by the arguments
        return (type(self), (self.path, self.problem))


class MissingDependencyError(Clutt3rError, ImportError):
    """An optional package needed by a backend is not installed."""

    def __init__(self, what: str, package: str, extra: str | None = None) -> None:
        self.what, self.package, self.extra = what, package, extra
        hint = f"pip install 'clutt3r[{extra}]'" if extra else f"pip install {package}"
        super().__init__(f"{what} needs the package '{package}', which is not installed: {hint}")

    def __reduce__(self):
        return (type(self), (self.what, self.package, self.extra))
