"""Errors users see: scene errors (ModelError) and run-time integration failures."""


class ModelError(ValueError):
    """A scene that cannot be built: names the file, line, key path and what would be valid."""

    def __init__(self, message, file=None, line=None, key=None, hint=None):
        self.file, self.line, self.key, self.hint = file, line, key, hint
        self.message = message
        where = ""
        if file is not None:
            where = f"{file}:{line}: " if line is not None else f"{file}: "
        elif line is not None:
            where = f"line {line}: "
        text = where + (f"{key}: " if key else "") + message
        if hint:
            text += f" ({hint})"
        super().__init__(text)


class IntegrationError(RuntimeError):
    """The integrator could not advance (tolerance not met, non-finite state or input)."""

    def __init__(self, message, t=None):
        self.t, self.message = t, message
        super().__init__(message if t is None else f"t={t:.9g}: {message}")


class EngineUnavailable(RuntimeError):
    """No compiled engine: no C compiler, or it failed."""
