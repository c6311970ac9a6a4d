"""torchik's exceptions: each says what is wrong and what would be right."""


class TorchikError(Exception):
    """Base class of torchik's errors."""


class ModelError(TorchikError):
    """A model file is missing or malformed, or a model name is unknown."""


class UnknownLinkError(TorchikError, KeyError):
    """A link name the model does not have."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


class InputError(TorchikError, ValueError):
    """A tensor of the wrong shape, dtype or device, or a value out of range."""


class MissingDependencyError(TorchikError):
    """An optional dependency is not installed; the message names the extra that brings it."""


def optional(module: str, extra: str, purpose: str):
    """Import an optional dependency (`module`), or raise MissingDependencyError saying which of
    torchik's extras installs it: `pip install 'torchik[extra]'`."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:
        if exc.name is not None and not module.startswith(exc.name):  # installed, but broken: its own error
            raise
        raise MissingDependencyError(f"{purpose} needs {module.split('.')[0]}, which is not installed: "
                                     f"pip install 'torchik[{extra}]'") from None
