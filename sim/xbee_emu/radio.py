"""One emulated XBee 3 radio: its AT parameter table and what it does with API frames.

Pure state machine (no I/O): `handle(frame)` returns what the radio answers on its UART
(`Reply`) and what it puts on the air (`Transmit`); the `Medium` does the timing and the
ptys. What is emulated follows docs/radios.md, which was read off digi-xbee 1.5.0's
`open()`: AT requests arrive as 0x09 (queued) as well as 0x08, HV must start with an
XBee 3 code, VR's first digit selects the protocol. Where the three firmwares answer
differently (a unicast nobody gets, CH and SC, payload limits, receive options) each
answer follows the Digi user guide named in docs/radios.md's per-firmware tables.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from swarmd.transport.media import MAX_PAYLOAD, MAX_PAYLOAD_ENCRYPTED, PROTOCOLS

# Firmware versions digi-xbee maps to each protocol on XBee 3 hardware (docs/radios.md).
_VR = {"zigbee": b"\x10\x0d", "802.15.4": b"\x20\x14", "digimesh": b"\x30\x0d"}
HV_XBEE3 = b"\x42\x40"

BROADCAST64 = 0x000000000000FFFF

# AT status codes in a 0x88 response.
AT_OK = 0
AT_ERROR = 1
AT_INVALID_COMMAND = 2
AT_INVALID_PARAMETER = 3
# Delivery status in 0x8B / 0x89 (Digi API reference).
TX_OK = 0x00
TX_NO_ACK = 0x01  # 802.15.4 "No ACK received"; DigiMesh/Zigbee "MAC ACK failure"
TX_NETWORK_ACK_FAILURE = 0x21
TX_SELF_ADDRESSED = 0x23
TX_ADDRESS_NOT_FOUND = 0x24
TX_ROUTE_NOT_FOUND = 0x25
TX_PAYLOAD_TOO_LARGE = 0x74
# Discovery status in a 0x8B.
NO_DISCOVERY = 0x00
ADDRESS_DISCOVERY = 0x01
ROUTE_DISCOVERY = 0x02
# The 0x8B's 16-bit field when a Zigbee unicast was not delivered ("destination address
# unknown"); DigiMesh and 802.15.4 keep it reserved at 0xFFFE.
UNKNOWN16 = 0xFFFD
UNKNOWN64 = 0xFFFFFFFFFFFFFFFF  # a 0x10 addressed by its 16-bit field only
# DigiMesh delivery method: bits 6-7 of the transmit options (0 there: the TO
# parameter's) and of the receive options of a 0x90.
METHOD_MASK = 0xC0
POINT_MULTIPOINT = 0x40
DIRECTED_BROADCAST = 0x80
DIGIMESH = 0xC0
# 2.4 GHz channels (CH on 802.15.4 and DigiMesh); bit i of Zigbee's SC is channel 11 + i.
CHANNELS = range(0x0B, 0x1B)
# Zigbee payloads (XBee 3 Zigbee guide, "Maximum RF payload size"): one packet carries
# 84 B unicast / 92 B broadcast (66 / 74 B with EE=1); a unicast of up to 255 B goes out
# in fragments, a broadcast never does. NP reads 0xFF in API mode.
ZIGBEE_UNICAST_PACKET = {False: 84, True: 66}
ZIGBEE_FRAGMENTED_MAX = 255
# Remote AT status (0x97) when the target never answered.
REMOTE_NO_RESPONSE = 0x04
# A 16-bit address that is not one: MY=0xFFFE (or 0xFFFF) makes an 802.15.4 radio send
# with its 64-bit source; a 0x17 with dest16 0xFFFE addresses by 64 bits.
NO_ADDRESS16 = frozenset((0xFFFE, 0xFFFF))
BROADCAST16 = 0xFFFF

# API frame types each firmware takes from its UART (Digi's XBee 3 manuals). The
# 802.15.4 firmware keeps the legacy TX64 (0x00) / TX16 (0x01) requests; Zigbee and
# DigiMesh do not know them. Anything else is dropped without an answer (the guides name
# none for an unknown type) and counted (`unsupported_frame`).
ACCEPTED_FRAMES = {
    "802.15.4": frozenset((0x00, 0x01, 0x08, 0x09, 0x10, 0x17)),
    "zigbee": frozenset((0x08, 0x09, 0x10, 0x17)),
    "digimesh": frozenset((0x08, 0x09, 0x10, 0x17)),
}

# Width in bytes of numeric parameters (values set with other widths are normalised).
_WIDTH = {
    "AP": 1, "CE": 1, "CH": 1, "ID": 2, "MY": 2, "DH": 4, "DL": 4, "SH": 4, "SL": 4,
    "SM": 1, "NP": 2, "EE": 1, "AI": 1, "BD": 1, "RO": 1, "NO": 1, "HV": 2, "VR": 2,
    "MM": 1, "TO": 1, "SC": 2,
}
_READ_ONLY = frozenset({"HV", "VR", "SH", "SL", "NP", "AI"})


@dataclass(frozen=True, slots=True)
class Reply:
    """API frame data the radio writes to its UART."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Transmit:
    """A transmit request accepted from the UART, to be put on the air by the medium."""

    frame_id: int
    request_type: int  # 0x10 (Transmit Request), 0x00 (TX64) or 0x01 (TX16, 802.15.4)
    dest64: int
    data: bytes
    dest16: int | None = None
    """Only for 0x01: the 16-bit destination (0xFFFF broadcast, else a radio's MY)."""
    network16: int = 0xFFFE
    """Only for 0x10: its 16-bit destination field (0xFFFE: address by `dest64`)."""
    options: int = 0
    """Only for 0x10: its transmit options (DigiMesh: bits 6-7, the delivery method)."""

    @property
    def broadcast(self) -> bool:
        if self.dest16 is not None:
            return self.dest16 == BROADCAST16
        return self.dest64 == BROADCAST64 or (
            self.dest64 == UNKNOWN64 and self.network16 == BROADCAST16)


@dataclass(frozen=True, slots=True)
class RemoteCommand:
    """A Remote AT Command Request (0x17) to be carried over the air to its target."""

    frame_id: int
    dest64: int
    dest16: int
    options: int  # bit 0x02: apply now (else queued until AC, like 0x09)
    command: bytes  # two ASCII letters as sent
    value: bytes

    @property
    def broadcast(self) -> bool:
        return self.dest64 == BROADCAST64


Output = Reply | Transmit | RemoteCommand


@dataclass
class EmulatedRadio:
    """State of one radio. `number` is 1-based and names the pty symlink."""

    number: int
    protocol: str
    api_mode: int = 1
    pan_id: int = 0x0607
    channel: int = 0x0C
    coordinator: bool = False
    loss: float = 0.0
    """Probability that a frame this radio sends, or one sent to it, is lost."""
    delay: float = 0.0
    """s. Extra latency added to every frame this radio sends."""
    params: dict[str, bytes] = field(default_factory=dict)
    saved: dict[str, bytes] = field(default_factory=dict)
    pending: dict[str, bytes] = field(default_factory=dict)
    counters: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.protocol not in PROTOCOLS:
            raise ValueError(f"unknown protocol {self.protocol!r}; one of {PROTOCOLS}")
        if self.api_mode not in (1, 2):
            raise ValueError("api_mode must be 1 or 2")
        n = self.number
        p = self._factory_params()
        if self.protocol == "zigbee":
            # Zigbee: the network assigns MY; the coordinator is always 0x0000. CH is the
            # operating channel (read-only), picked from the SC mask (every radio of a
            # Medium starts on the medium's channel, as one formed network).
            p["MY"] = b"\x00\x00" if self.coordinator else (0x1000 + n).to_bytes(2, "big")
            p["SM"] = b"\x00"
            p["SC"] = (0x7FFF).to_bytes(2, "big")  # factory default: channels 11-25
            p["TO"] = b"\x00"
        elif self.protocol == "digimesh":
            p["TO"] = bytes((DIGIMESH,))  # factory default delivery method
        elif self.protocol == "802.15.4":
            # Factory default MY=0 makes the radio send with 16-bit source addresses, the
            # ones that trip digi-xbee (xbee-python #296); the transport sets 0xFFFE.
            p["MY"] = b"\x00\x00"
            # Channels an association scan looks at (scans are not emulated: stored only;
            # 0 means "the CH channel").
            p["SC"] = (0x1FFE).to_bytes(2, "big")
        # DigiMesh has no MY and no SS on XBee 3: both answer "invalid command".
        self.params = p
        self.saved = dict(p)

    def _factory_params(self) -> dict[str, bytes]:
        """The AT parameters every protocol has, at their factory values (with this
        radio's number, network and API mode)."""
        n = self.number
        return {
            "AP": bytes((self.api_mode,)),
            "HV": HV_XBEE3,
            "VR": _VR[self.protocol],
            "SH": (0x0013A200).to_bytes(4, "big"),
            "SL": (0x40000000 + n).to_bytes(4, "big"),
            "NI": f"robot{n}".encode(),
            "CE": b"\x01" if self.coordinator else b"\x00",
            "ID": self.pan_id.to_bytes(2, "big"),
            "CH": bytes((self.channel,)),
            "DH": b"\x00\x00\x00\x00",
            "DL": b"\x00\x00\x00\x00",
            "NP": MAX_PAYLOAD[self.protocol].to_bytes(2, "big"),
            "EE": b"\x00",
            "AI": b"\x00",
            "BD": b"\x03",  # 9600 baud
        }

    # -- derived ------------------------------------------------------------------------
    @property
    def address64(self) -> int:
        return int.from_bytes(self.params["SH"] + self.params["SL"], "big")

    @property
    def my16(self) -> int:
        return int.from_bytes(self.params.get("MY", b"\xff\xfe"), "big")

    @property
    def current_api_mode(self) -> int:
        return self.params["AP"][0]

    @property
    def network(self) -> tuple[str, bytes, bytes]:
        """Radios hear each other when protocol, PAN id and channel all match."""
        return (self.protocol, self.params["ID"], self.params["CH"])

    @property
    def encrypted(self) -> bool:
        return self.params["EE"] != b"\x00"

    @property
    def max_payload(self) -> int:
        """Largest broadcast payload (one packet; what transparent mode packetises)."""
        table = MAX_PAYLOAD_ENCRYPTED if self.encrypted else MAX_PAYLOAD
        return table[self.protocol]

    def payload_limit(self, request: Transmit) -> int:
        """Largest payload `request` may carry; more is refused with status 0x74."""
        if self.protocol == "zigbee" and not request.broadcast:
            return ZIGBEE_FRAGMENTED_MAX
        return self.max_payload

    def packets(self, request: Transmit) -> list[int]:
        """Payload bytes of each RF packet `request` goes out in (Zigbee fragments a
        unicast longer than one packet)."""
        size = len(request.data)
        if self.protocol != "zigbee" or request.broadcast:
            return [size]
        step = ZIGBEE_UNICAST_PACKET[self.encrypted]
        return [min(step, size - start) for start in range(0, size, step)] or [0]

    def delivery_method(self, request: Transmit) -> int:
        """DigiMesh: the request's delivery method bits, else the TO parameter's."""
        if self.protocol != "digimesh":
            return 0
        return (request.options & METHOD_MASK or self.params["TO"][0] & METHOD_MASK
                or DIGIMESH)

    def np_value(self) -> bytes:
        """NP as read. Zigbee in API mode: 0xFF (the fragmented unicast maximum)."""
        if self.protocol == "zigbee":
            return ZIGBEE_FRAGMENTED_MAX.to_bytes(2, "big")
        return self.max_payload.to_bytes(2, "big")

    def count(self, name: str) -> None:
        self.counters[name] = self.counters.get(name, 0) + 1

    def power_cycle(self) -> None:
        """Unplugging loses everything not written with WR (as on the real radio)."""
        self.params = dict(self.saved)
        self.pending.clear()

    # -- UART input ---------------------------------------------------------------------
    def handle(self, frame: bytes) -> list[Output]:
        """Process one API frame's data (frame type first)."""
        ftype = frame[0]
        if ftype not in ACCEPTED_FRAMES[self.protocol]:
            self.count("unsupported_frame")
            return []
        if ftype in (0x08, 0x09) and len(frame) >= 4:
            return self._at(frame, queued=ftype == 0x09)
        if ftype == 0x10 and len(frame) >= 14:
            # type, frame id, dest64, dest16, broadcast radius, options, data
            return [Transmit(frame[1], 0x10, int.from_bytes(frame[2:10], "big"), frame[14:],
                             network16=int.from_bytes(frame[10:12], "big"),
                             options=frame[13])]
        if ftype == 0x00 and len(frame) >= 11:
            return [Transmit(frame[1], 0x00, int.from_bytes(frame[2:10], "big"), frame[11:])]
        if ftype == 0x01 and len(frame) >= 5:
            # type, frame id, dest16, options, data
            dest16 = int.from_bytes(frame[2:4], "big")
            dest64 = BROADCAST64 if dest16 == BROADCAST16 else 0
            return [Transmit(frame[1], 0x01, dest64, frame[5:], dest16=dest16)]
        if ftype == 0x17 and len(frame) >= 15:
            # type, frame id, dest64, dest16, options, command, [value]
            return [RemoteCommand(frame[1], int.from_bytes(frame[2:10], "big"),
                                  int.from_bytes(frame[10:12], "big"), frame[12],
                                  bytes(frame[13:15]), bytes(frame[15:]))]
        self.count("short_frame")  # a known type cut short: the radio drops it too
        return []

    def _at(self, frame: bytes, *, queued: bool) -> list[Output]:
        fid = frame[1]
        try:
            cmd = frame[2:4].decode("ascii").upper()
        except UnicodeDecodeError:
            cmd = "??"
        value = frame[4:]
        status, answer = self._command(cmd, value, queued=queued)
        if fid == 0:
            return []  # frame id 0: the host asked for no response
        return [Reply(bytes((0x88, fid)) + frame[2:4] + bytes((status,)) + answer)]

    def remote_command(self, request: RemoteCommand) -> tuple[int, bytes]:
        """Run a remote AT command that reached this radio: (status, value)."""
        try:
            cmd = request.command.decode("ascii").upper()
        except UnicodeDecodeError:
            cmd = "??"
        return self._command(cmd, request.value, queued=not request.options & 0x02)

    def reached_by(self, request: Transmit) -> bool:
        """Whether the unicast `request` is for this radio. A 0x10's 16-bit field, when
        it holds an address, is what Zigbee routes by (and 802.15.4 sends to); on
        Zigbee the 64-bit address 0 is the coordinator."""
        if request.request_type != 0x10:
            return self.addressed_by(request.dest64, request.dest16)
        if request.network16 not in NO_ADDRESS16 and self.protocol != "digimesh":
            return self.my16 not in NO_ADDRESS16 and self.my16 == request.network16
        if self.protocol == "zigbee" and request.dest64 == 0:
            return self.params["CE"] == b"\x01"
        return self.address64 == request.dest64

    def unicast_failure(self, request: Transmit, *, lost: bool) -> tuple[int, int]:
        """(delivery status, discovery status) of a unicast that did not arrive: the
        addressee did not acknowledge it (`lost`), or no radio has its address."""
        if self.protocol == "802.15.4":
            return TX_NO_ACK, NO_DISCOVERY  # the MAC frame was never acknowledged
        if self.protocol == "digimesh":
            if self.delivery_method(request) == POINT_MULTIPOINT:
                return TX_NO_ACK, NO_DISCOVERY  # one hop, MAC acknowledgements only
            if lost:
                return TX_NETWORK_ACK_FAILURE, NO_DISCOVERY
            return TX_ROUTE_NOT_FOUND, ROUTE_DISCOVERY
        if lost:
            return TX_NETWORK_ACK_FAILURE, NO_DISCOVERY
        if (request.network16 == self.my16 if request.network16 not in NO_ADDRESS16
                else request.dest64 == self.address64):
            return TX_SELF_ADDRESSED, NO_DISCOVERY
        if request.network16 in NO_ADDRESS16:
            return TX_ADDRESS_NOT_FOUND, ADDRESS_DISCOVERY  # the broadcast lookup failed
        return TX_NETWORK_ACK_FAILURE, NO_DISCOVERY  # sent to a 16-bit nobody has

    def addressed_by(self, dest64: int, dest16: int | None) -> bool:
        """Whether a unicast to (dest64, dest16) is for this radio. A 16-bit address
        reaches only an 802.15.4 radio whose MY is that address (not 0xFFFE/0xFFFF)."""
        if dest16 is not None and dest16 not in NO_ADDRESS16:
            return (self.protocol == "802.15.4" and self.my16 not in NO_ADDRESS16
                    and self.my16 == dest16)
        return self.address64 == dest64

    def remote_response(self, request: RemoteCommand, status: int,
                        value: bytes) -> bytes:
        """The 0x97 this radio's requester gets back from the radio that ran it."""
        src16 = self.my16 if self.protocol != "digimesh" else 0xFFFE
        return (bytes((0x97, request.frame_id)) + self.address64.to_bytes(8, "big")
                + src16.to_bytes(2, "big") + request.command + bytes((status,)) + value)

    def _command(self, cmd: str, value: bytes, *, queued: bool) -> tuple[int, bytes]:
        if not queued:
            # A 0x08 (query or set) applies what 0x09 frames queued, as AC does (Digi:
            # "AT Command - Queue Parameter Value frame - 0x09").
            self._apply()
        if cmd == "AC":
            self._apply()
            return AT_OK, b""
        if cmd == "WR":
            self._apply()
            self.saved = dict(self.params)
            return AT_OK, b""
        if cmd in ("FR", "RE"):
            if cmd == "RE":
                return AT_OK, b""  # defaults not modelled; acknowledge
            self.power_cycle()
            return AT_OK, b""
        if cmd not in self.params:
            return AT_INVALID_COMMAND, b""
        if not value:
            return AT_OK, self.np_value() if cmd == "NP" else self.params[cmd]
        if cmd in _READ_ONLY or (cmd in ("MY", "CH") and self.protocol == "zigbee"):
            # Zigbee: the network assigns MY, and CH is the channel the network runs
            # on; SC is the mask a coordinator forms and a router joins in.
            return AT_ERROR, b""
        norm = self._normalise(cmd, value)
        if norm is None or not self._valid(cmd, norm):
            return AT_INVALID_PARAMETER, b""
        if queued:
            self.pending[cmd] = norm  # 0x09: held until AC (or the next 0x08)
        else:
            self.params[cmd] = norm
            self._settle()
        return AT_OK, b""

    def _valid(self, cmd: str, value: bytes) -> bool:
        if cmd == "AP":
            # Transparent mode would take this radio off the API: not emulated here.
            return value[0] in (1, 2)
        if cmd == "CH":
            return value[0] in CHANNELS  # 802.15.4 and DigiMesh: 0x0B-0x1A
        if cmd == "SC" and self.protocol == "zigbee":
            return value != b"\x00\x00"  # at least one channel to form or join on
        return True

    def _settle(self) -> None:
        """Zigbee: a mask without the operating channel moves the radio to the lowest
        channel the mask allows (it leaves and forms or joins anew; every radio with
        the same mask ends up on the same channel)."""
        if self.protocol != "zigbee":
            return
        mask = int.from_bytes(self.params["SC"], "big")
        channel = self.params["CH"][0]
        if not mask >> (channel - CHANNELS.start) & 1:
            lowest = (mask & -mask).bit_length() - 1
            self.params["CH"] = bytes((CHANNELS.start + lowest,))

    def _normalise(self, cmd: str, value: bytes) -> bytes | None:
        width = _WIDTH.get(cmd)
        if width is None:
            return bytes(value)
        number = int.from_bytes(value, "big")
        if number >= 1 << (8 * width):
            return None
        return number.to_bytes(width, "big")

    def _apply(self) -> None:
        if self.pending:
            self.params.update(self.pending)
            self.pending.clear()
            self._settle()

    # -- air side -----------------------------------------------------------------------
    def status_frame(self, request: Transmit, status: int, *,
                     discovery: int = NO_DISCOVERY, to16: int = 0xFFFE) -> bytes | None:
        """The transmit status for `request` (None when frame id 0 asked for none).
        `to16`: Zigbee's 16-bit field (where it went, or 0xFFFD when it did not)."""
        if request.frame_id == 0:
            return None
        if request.request_type in (0x00, 0x01):
            return bytes((0x89, request.frame_id, status))
        return (bytes((0x8B, request.frame_id)) + to16.to_bytes(2, "big")
                + bytes((0x00, status, discovery)))

    def receive_frame(self, sender: EmulatedRadio, data: bytes, broadcast: bool,
                      method: int = 0) -> bytes:
        """What this radio writes to its UART when it receives `data` from `sender`
        (`method`: the DigiMesh delivery method, carried in the receive options)."""
        options = (0x02 if broadcast else 0x01) | method
        if self.protocol == "802.15.4":
            rssi = 0x28  # -40 dBm
            # The sender's MY picks the MAC source address: 0xFFFE/0xFFFF send the
            # 64-bit one (received as 0x80), any other the 16-bit MY (0x81).
            if sender.my16 in NO_ADDRESS16:
                return bytes((0x80,)) + sender.address64.to_bytes(8, "big") + bytes(
                    (rssi, options)) + data
            return bytes((0x81,)) + sender.my16.to_bytes(2, "big") + bytes(
                (rssi, options)) + data
        src16 = sender.my16 if self.protocol == "zigbee" else 0xFFFE
        return (bytes((0x90,)) + sender.address64.to_bytes(8, "big")
                + src16.to_bytes(2, "big") + bytes((options,)) + data)
