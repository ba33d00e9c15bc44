"""qz_drake: the hexapod Qingzhui planning and walking across rough terrain, on Drake."""

from qz_drake.errors import QzError

__all__ = ["QzError"]
__version__ = "0.1.0"
