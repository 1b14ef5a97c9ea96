"""nmtcheck: offline CANopen NMT trace analysis and CiA 301 compliance checking."""

__version__ = "0.1.0"
