"""Specific exceptions of sofia_ros.

Every error a user can cause (bad argument, config, command, bag) is one of
these; the CLI turns them into one line on stderr and exit code 2. Wrap
lower-level exceptions with ``raise ... from err`` so the cause is kept.
"""

from __future__ import annotations

__all__ = [
    'SofiaError',
    'InvalidArgumentError',
    'NotOrthonormalError',
    'UnknownStarError',
    'BelowHorizonError',
    'ConfigError',
    'OutputError',
    'PerturbationError',
    'UnknownEffectError',
    'CommandRefusedError',
    'BagError',
    'FitError',
    'ForkedWorkerError',
    'DomainBusyError',
    'CalibrationAbort',
    'SchedulerUnreachableError',
    'RunFaultError',
    'GraphRunError',
    'RunInterrupted',
]


class SofiaError(Exception):
    """Base of every error sofia_ros raises on purpose."""


class InvalidArgumentError(SofiaError, ValueError):
    """An argument has the wrong shape, type, range, or holds NaN/inf."""


class NotOrthonormalError(InvalidArgumentError):
    """A matrix given as a DCM is not orthonormal within tolerance."""


class UnknownStarError(SofiaError, LookupError):
    """A star name or HIP number is not in the catalogue."""


class BelowHorizonError(SofiaError):
    """A star is below the horizon or below the telescope's elevation limit."""


class ConfigError(SofiaError):
    """A truth, model or node configuration is malformed or out of range."""


class OutputError(ConfigError):
    """An output cannot be written: ``exit_code`` 3 when the machine ran out of space, 2 when the path is at fault."""

    def __init__(self, message, exit_code=2):
        super().__init__(message)
        self.exit_code = exit_code


class PerturbationError(ConfigError):
    """A `sofia perturb` request is malformed: observable, unit, shape expression or output path."""


class UnknownEffectError(ConfigError):
    """A configuration names an effect that is not in the catalogue."""


class CommandRefusedError(SofiaError):
    """A telescope command is outside the fine- or coarse-drive limits."""


class BagError(SofiaError):
    """A bag is missing, corrupt, truncated or lacks the needed topics."""


class FitError(SofiaError):
    """A model cannot be fitted to a bag's measurements (it sends stars off their detectors)."""


class ForkedWorkerError(SofiaError):
    """A forked worker of ``--jobs`` died before it returned its result, or its result could not be returned."""


class DomainBusyError(ConfigError):
    """Another run on this machine holds the ROS domain (its lock file); two graphs in one domain corrupt each other."""


class CalibrationAbort(SofiaError):
    """The calibration node's sequence cannot go on (a timeout, a refused command); the reason says why."""


class SchedulerUnreachableError(SofiaError):
    """`sofia atlas --scheduler ADDRESS`: no Dask scheduler answers at that address within the timeout."""


class RunFaultError(SofiaError):
    """A campaign stopped by a fault after it started (a node died, the graph stalled); its bag is closed."""


class GraphRunError(RunFaultError):
    """The live graph did not finish (stall, crash, a node process died, or the wall-clock timeout)."""


class RunInterrupted(BaseException):
    """SIGINT or SIGTERM stopped a run; BaseException like KeyboardInterrupt, so no ``except Exception`` swallows it."""

    def __init__(self, signum, message=''):
        import signal

        self.signum = int(signum)
        self.signal_name = signal.Signals(self.signum).name
        super().__init__(message or f'interrupted by {self.signal_name}')
