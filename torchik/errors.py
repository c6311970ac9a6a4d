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
