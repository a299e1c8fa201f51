"""idm: a Python client of idmd, the piezoelectric stick-slip nanopositioner daemon.

Pure standard library. ``idm.Client`` (synchronous) and ``idm.aio.AsyncClient`` (asyncio)
speak idmd's SCPI-style line protocol over TCP or its Unix socket; ``client.axis(n or name)``
gives an :class:`Axis` (move, move_by, step, stop, position, status, reference, sweep, ...);
``axis.movable()`` a Bluesky-style movable (:mod:`idm.bluesky`); :mod:`idm.units` reads and
writes lengths with units ("250nm"). Every error the daemon queues
is raised as :class:`ScpiError` with its code and text.
"""

from . import units
from .address import DEFAULT_PORT, address_from_environment
from .client import Axis, Client, Sweep
from ._core import AxisNotFound
from ._sweep import SweepProgress
from .errors import (CommandError, DeviceFault, DeviceSpecificError, ExecutionError,
                     IdmConnectionError, IdmError, IdmTimeout, MoveError, MoveStopped,
                     ProtocolError, QueryError, ScpiError, SweepError)
from .status import (AxisStatus, EventStatus, LoopStats, MoveResult, Operation, StatusByte,
                     SweepState)

__version__ = "0.1.0"

__all__ = [
    "Client", "Axis", "Sweep", "SweepProgress", "DEFAULT_PORT", "address_from_environment",
    "units",
    "AxisStatus", "Operation", "StatusByte", "EventStatus", "MoveResult", "SweepState",
    "LoopStats",
    "IdmError", "ScpiError", "CommandError", "ExecutionError", "DeviceSpecificError",
    "QueryError", "DeviceFault", "IdmTimeout", "IdmConnectionError", "ProtocolError",
    "MoveError", "MoveStopped", "SweepError", "AxisNotFound",
    "__version__",
]
