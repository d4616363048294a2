"""The exceptions magfit raises.

All derive from :class:`MagfitError`, itself a :class:`ValueError`, so callers that only know
"bad value" still catch them. Each message says what is wrong and what to do about it.
"""

from __future__ import annotations

__all__ = ["CalibrationError", "DataFileError", "ExportError", "MagfitError", "OptionError", "SampleError"]


class MagfitError(ValueError):
    """Base class of every error magfit raises on purpose.

    Besides its one-line message, an error carries its reasons as data: ``codes`` (the stable reason codes of
    :data:`magfit.REASON_CODES`, empty where none was given) and ``remedy`` (``(argument, value)`` pairs the
    command line renders as ``--flags`` and Python as keywords). Code that decides reads these, not the words.
    """

    def __init__(self, *args: object, codes: tuple[str, ...] = (), remedy: tuple[tuple[str, str], ...] = ()) -> None:
        super().__init__(*args)
        self.codes = tuple(codes)
        self.remedy = tuple(remedy)
        #: The message's closing words when they name remedies in general (``"; on a vehicle, ..."``): a caller
        #: that knows better (the file's own columns) says its advice instead, with :meth:`without_general_advice`.
        self.general_advice = ""

    def without_general_advice(self) -> str:
        """The message without its :attr:`general_advice`."""
        message = str(self)
        if self.general_advice and message.endswith(self.general_advice):
            return message[: -len(self.general_advice)]
        return message


class SampleError(MagfitError):
    """The samples array itself is malformed: wrong shape, wrong type or non-finite values."""


class OptionError(MagfitError):
    """An unknown method, an unknown option, or an option value out of range."""


class CalibrationError(MagfitError):
    """The data are well-formed but cannot support the requested fit.

    Too few samples, all samples identical, samples that do not span three dimensions, or a fitted
    quadric that is not an ellipsoid. The message names the reason and suggests a remedy.
    """


class DataFileError(MagfitError):
    """A data or calibration file cannot be read: missing, empty, malformed cells or rows."""


class ExportError(MagfitError):
    """A firmware export cannot represent the calibration (out of the target's range, or no unit to convert)."""
