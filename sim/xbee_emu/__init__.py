"""Software XBee radios for running swarmd without hardware.

    with Medium(6, protocol="802.15.4", directory=tmp) as medium:
        XBeeDevice(medium.path(1), 9600).open()   # the real digi-xbee library
        medium.unplug(2); medium.replug(2)

`swarmd xbee emulate N` runs the same thing from the command line.
"""

from sim.xbee_emu.medium import DEFAULT_DIR, Medium
from sim.xbee_emu.radio import EmulatedRadio
from swarmd.transport.media import MAX_PAYLOAD, PROTOCOLS

__all__ = ["DEFAULT_DIR", "MAX_PAYLOAD", "PROTOCOLS", "EmulatedRadio", "Medium"]
