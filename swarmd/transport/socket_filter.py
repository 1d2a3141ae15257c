"""What never wakes the daemon: datagrams dropped in the kernel by a classic BPF program
on the UDP transport's receiving socket (SO_ATTACH_FILTER, as tcpdump attaches its own;
Linux only, no privilege needed). Two kinds, each dropped here only where the core would
drop it anyway before any check, so what a robot does is unchanged:

- our own datagrams (`drop_own`). The transport sends from a socket of its own
  (`udp.py`), so every datagram it sends carries that socket's address and port as its
  source; with multicast loopback on (the default: the swarm of a simulation shares one
  host) the kernel hands each back to every member of the group on the host, our
  receiving socket too. Only that address *and* port are dropped, which no other process
  can hold while we do: a frame in our name sent by anyone else (another daemon with our
  robot id, a forger) still arrives and is judged by the core (`own`, `duplicate_id`:
  DESIGN section 2, "Sequence numbers"; docs/daemon.md). A host that forges that very
  source too loses its frame unseen, where the core would have dropped it as `own`.
- heartbeats about what this robot does not hear (`SwarmPlan.unheard`; DESIGN section 2,
  "What a robot hears"): the frames `Node._irrelevant` drops first thing, before the tag, the
  signature, the replay filter or any state, judged by the same fields (swarm, type,
  slot, sender). Only heartbeats, the traffic that comes every period; the rare WARN,
  CLAIM or LEAVE about another slot still reaches the core, which drops it as before.

On a UDP socket the program sees the datagram from its UDP header (offset 8 is the
frame's first byte); the IP header is reached through the kernel's SKF_NET_OFF base (the
source address at 12). A load past the end of a datagram would end the program with
"drop", so the length is checked before any byte of the frame is read: a datagram too
short for a heartbeat is kept, for the core to count as `malformed`. `attach` returns
False where the kernel or the platform refuses: the transport then works without it.
"""

from __future__ import annotations

import ctypes
import ipaddress
import socket
import struct
import sys
from typing import NamedTuple

from swarmd.core.plan import Unheard

SO_ATTACH_FILTER = getattr(socket, "SO_ATTACH_FILTER", 26)
"""Linux's value (asm-generic/socket.h); Python's socket module does not name it."""
SKF_NET_OFF = -0x100000
"""linux/filter.h: a load at this base + n reads the IP header's byte n."""
MAX_INSNS = 4096
"""BPF_MAXINSNS: the longest program the kernel takes."""
MAX_JUMP = 255
"""A conditional jump skips at most this many instructions (8-bit offsets)."""

_UDP = 8
"""The frame's first byte, after the UDP header."""
_FIRST, _SWARM, _SENDER, _SLOT = _UDP, _UDP + 1, _UDP + 3, _UDP + 11
"""Where wire.py's header puts byte 0, the swarm id, the sender and a heartbeat's slot."""
_HEARTBEAT_MIN = _UDP + 11 + 3
"""The shortest datagram `wire.peek` reads a heartbeat's slot from."""
_VERSION_TYPE_MASK = 0xF7  # byte 0 without its "signed" bit
_HEARTBEAT_V1 = 0x11  # version 1, type HEARTBEAT

# Classic BPF opcodes (linux/bpf_common.h).
_LD_W_ABS, _LD_H_ABS, _LD_B_ABS, _LD_W_LEN = 0x20, 0x28, 0x30, 0x80
_AND_K, _TAX, _TXA = 0x54, 0x07, 0x87
_JA, _JEQ_K, _JGE_K = 0x05, 0x15, 0x35
_RET_K = 0x06  # keep k bytes of the datagram: 0 drops it
_KEEP = 0xFFFFFFFF
_INSN = struct.Struct("=HBBI")
"""struct sock_filter: code, jt, jf, k in the host's byte order."""


class _Program:
    """Instructions with forward jumps to labels, resolved at the end."""

    def __init__(self) -> None:
        self.insns: list[tuple[int, str | int, str | int, int]] = []
        self.labels: dict[str, int] = {}

    def op(self, code: int, k: int = 0) -> None:
        self.insns.append((code, 0, 0, k & 0xFFFFFFFF))

    def jump(self, code: int, k: int, yes: str | int, no: str | int) -> None:
        """`yes` / `no`: a label, or how many instructions to skip (0: the next)."""
        self.insns.append((code, yes, no, k & 0xFFFFFFFF))

    def go_if(self, code: int, k: int, label: str) -> None:
        """To `label` if the test holds, through an unconditional jump (32-bit offset):
        a conditional one reaches at most `MAX_JUMP` instructions on."""
        self.jump(code, k, 0, 1)
        self.jump(_JA, 0, label, label)

    def go_unless(self, code: int, k: int, label: str) -> None:
        self.jump(code, k, 1, 0)
        self.jump(_JA, 0, label, label)

    def label(self, name: str) -> None:
        self.labels[name] = len(self.insns)

    def code(self) -> bytes | None:
        """The program, or None if it is too long or a jump too far for classic BPF."""
        out = []
        for at, (code, yes, no, k) in enumerate(self.insns):
            if code == _JA:
                out.append(_INSN.pack(code, 0, 0, self._offset(at, yes)))
                continue
            jt, jf = self._offset(at, yes), self._offset(at, no)
            if max(jt, jf) > MAX_JUMP:
                return None
            out.append(_INSN.pack(code, jt, jf, k))
        return b"".join(out) if len(out) <= MAX_INSNS else None

    def _offset(self, at: int, target: str | int) -> int:
        return self.labels[target] - at - 1 if isinstance(target, str) else target


class Filter(NamedTuple):
    """A program (`code`) and whether it drops the unheard heartbeats too (`unheard`)."""

    code: bytes
    unheard: bool


def program(own: tuple[str, int] | None, unheard: Unheard | None) -> Filter | None:
    """The instructions that drop our own datagrams (from `own`, an address and port)
    and the heartbeats `unheard` says, and keep any other datagram whole; None when
    there is nothing to drop. Without the unheard heartbeats when they would not fit
    classic BPF (a swarm of thousands of robots: the core then drops them as before)."""
    if own is None and unheard is None:
        return None
    p = _Program()
    if own is not None:
        _drop_own(p, *own)
    if unheard is not None:
        _drop_unheard(p, unheard)
    p.label("keep")
    p.op(_RET_K, _KEEP)
    p.label("drop")
    p.op(_RET_K, 0)
    code = p.code()
    if code is None:
        return program(own, None) if unheard is not None else None
    return Filter(code, unheard is not None)


def _drop_own(p: _Program, address: str, port: int) -> None:
    """Source port, then source address: both ours, drop."""
    p.op(_LD_H_ABS, 0)
    p.go_unless(_JEQ_K, port, "others")
    p.op(_LD_W_ABS, SKF_NET_OFF + 12)
    p.go_if(_JEQ_K, int(ipaddress.IPv4Address(address)), "drop")
    p.label("others")


def _drop_unheard(p: _Program, unheard: Unheard) -> None:
    """A heartbeat of our swarm about a slot we do not hear, from a robot of the plan
    but us; or a standby's from one whose heartbeats we do not hear."""
    p.op(_LD_W_LEN)
    p.go_unless(_JGE_K, _HEARTBEAT_MIN, "keep")
    p.op(_LD_B_ABS, _FIRST)
    p.op(_AND_K, _VERSION_TYPE_MASK)
    p.go_unless(_JEQ_K, _HEARTBEAT_V1, "keep")
    p.op(_LD_H_ABS, _SWARM)
    p.go_unless(_JEQ_K, unheard.swarm_id, "keep")
    p.op(_LD_H_ABS, _SENDER)
    p.op(_TAX)  # X = sender
    p.op(_LD_B_ABS, _SLOT)
    p.go_if(_JEQ_K, 0, "standby")
    # A slot of two or three bytes (0x80 and up) is left to the core.
    p.go_if(_JGE_K, 0x80, "keep")
    _one_of(p, sorted(unheard.slots), "sender")
    p.label("sender")
    p.op(_TXA)
    _one_of(p, sorted(unheard.senders), "drop")
    p.label("standby")
    p.op(_TXA)
    _one_of(p, sorted(unheard.standbys), "drop")


def _one_of(p: _Program, values: list[int], then: str) -> None:
    """Go to `then` if A is one of `values`, else keep the datagram."""
    for v in values:
        p.go_if(_JEQ_K, v, then)
    p.jump(_JA, 0, "keep", "keep")


def attach(sock: socket.socket, code: bytes) -> bool:
    """Attach `code` to `sock`; False where the platform or the kernel refuses."""
    if not sys.platform.startswith("linux"):
        return False  # the option number means something else there, or nothing
    buffer = ctypes.create_string_buffer(code, len(code))
    fprog = _SockFprog(len(code) // _INSN.size, ctypes.addressof(buffer))
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, bytes(fprog))
    except OSError:
        return False
    return True


class _SockFprog(ctypes.Structure):
    """struct sock_fprog: the program's length and where its instructions are."""

    _fields_ = (("len", ctypes.c_ushort), ("filter", ctypes.c_void_p))


DROP_ALL = _INSN.pack(_RET_K, 0, 0, 0)
"""A program that drops every datagram (the sending socket reads nothing)."""

__all__ = ["DROP_ALL", "SKF_NET_OFF", "Filter", "attach", "program"]
