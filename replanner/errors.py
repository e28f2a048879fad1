"""One exception tree: everything replanner raises on purpose derives from ReplannerError."""

from __future__ import annotations


class ReplannerError(Exception):
    """Root of every error replanner raises on purpose.

    Errors keep their data across a process boundary: pickling restores the class, the message and every
    attribute (a contact, a solver's answer), whatever arguments the subclass's constructor takes.
    """

    def __reduce__(self):
        return _rebuild, (type(self), self.args, self.__dict__)


def _rebuild(cls: type, args: tuple, state: dict) -> ReplannerError:
    err = cls.__new__(cls)
    err.args = args
    err.__dict__.update(state)
    return err


class ConfigError(ReplannerError, ValueError):
    """A configuration file or value is wrong; the message names the field, the file and what is allowed."""

    def __init__(self, message: str, *, source: str | None = None, field: str | None = None):
        self.source = source
        self.field = field
        super().__init__(message)


class RobotModelError(ReplannerError):
    """The robot description (URDF, joint names, link names) cannot be used as given."""


class UnknownNameError(ReplannerError, KeyError):
    """A joint, link or world object name does not exist; the message lists the valid names."""

    def __init__(self, kind: str, name: str, valid: list[str] | tuple[str, ...]):
        self.kind = kind
        self.name = name
        self.valid = tuple(valid)
        shown = ", ".join(self.valid[:40]) + (" ..." if len(self.valid) > 40 else "")
        super().__init__(f"unknown {kind} {name!r}; valid {kind}s: {shown or '(none)'}")

    def __str__(self) -> str:  # KeyError would otherwise quote the whole message
        return self.args[0]


class InvalidInputError(ReplannerError, ValueError):
    """An array, pose or value given to the library has the wrong shape, dtype or range."""


class WorldError(ReplannerError):
    """A scene edit cannot be applied (duplicate name, attaching twice, ...)."""


class TrajectoryError(ReplannerError):
    """A path cannot be timed, spliced or braked as asked; the message says why."""
