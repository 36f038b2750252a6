"""The bench station: a compass module on a turntable turned into a four-flip recording (``compass bench``)."""

from .session import Instruction, SessionEnded, Station
from .sources import ColumnSource, GyroSource, ManualSource, parse_turntable
from .store import SessionStore, flips_folder, recording_path
from .stream import StationStream
from .turn import Reading, TurnData, TurnRejected

__all__ = ["Instruction", "SessionEnded", "Station", "ColumnSource", "GyroSource", "ManualSource", "parse_turntable",
           "SessionStore", "flips_folder", "recording_path", "StationStream", "Reading", "TurnData", "TurnRejected"]
