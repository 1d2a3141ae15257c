"""Our own multicast datagrams dropped in the kernel, before they wake the daemon.

The UDP transport sends from a socket of its own (`udp.py`), so every datagram it sends
carries that socket's address and port as its source; with multicast loopback on (the
default: the swarm of a simulation shares one host) the kernel hands each back to every
member of the group on the host, our receiving socket too. Without a filter that echo
wakes the event loop once per frame sent (10 a second at `udp()`) only for the core to
drop it as `own`. A classic BPF program on the receiving socket (SO_ATTACH_FILTER, as
tcpdump attaches its own; Linux only, no privilege needed) drops exactly the datagrams
whose source is our sending socket's address *and* port, which no other process can
hold while we do: a frame in our name sent by anyone else (another daemon with our
robot id, a forger) still arrives and is judged by the core as before (`own`,
`duplicate_id`: DESIGN section 2, "Sequence numbers"; docs/daemon.md).

On a UDP socket the program sees the datagram from its UDP header (offset 0 is the
source port); the IP header is reached through the kernel's SKF_NET_OFF base (the source
address at 12). `attach` returns False where the kernel or the platform refuses: the
transport then works as without it, the echoes reaching the core.
"""

from __future__ import annotations

import ctypes
import ipaddress
import socket
import struct
import sys

SO_ATTACH_FILTER = getattr(socket, "SO_ATTACH_FILTER", 26)
"""Linux's value (asm-generic/socket.h); Python's socket module does not name it."""
SKF_NET_OFF = -0x100000
"""linux/filter.h: a load at this base + n reads the IP header's byte n."""

# Classic BPF opcodes (linux/bpf_common.h).
_LD_H_ABS = 0x28  # BPF_LD | BPF_H | BPF_ABS: A = the 16-bit word at k, network order
_LD_W_ABS = 0x20  # BPF_LD | BPF_W | BPF_ABS: A = the 32-bit word at k
_JEQ_K = 0x15  # BPF_JMP | BPF_JEQ | BPF_K: A == k ? skip jt : skip jf
_RET_K = 0x06  # BPF_RET | BPF_K: keep k bytes of the datagram (0: drop it)
_KEEP = 0xFFFFFFFF
_INSN = struct.Struct("=HBBI")
"""struct sock_filter: code, jt, jf, k in the host's byte order."""


class _SockFprog(ctypes.Structure):
    """struct sock_fprog: the program's length and where its instructions are."""

    _fields_ = (("len", ctypes.c_ushort), ("filter", ctypes.c_void_p))


def drop_source_program(address: str, port: int) -> bytes:
    """The instructions that drop a datagram from `address`:`port` and keep any other,
    whole."""
    source = int(ipaddress.IPv4Address(address))
    insns = [
        (_LD_H_ABS, 0, 0, 0),  # A = UDP source port
        (_JEQ_K, 0, 3, port),  # not ours: keep
        (_LD_W_ABS, 0, 0, (SKF_NET_OFF + 12) & 0xFFFFFFFF),  # A = IP source address
        (_JEQ_K, 0, 1, source),  # not ours: keep
        (_RET_K, 0, 0, 0),  # our own datagram: drop
        (_RET_K, 0, 0, _KEEP),
    ]
    return b"".join(_INSN.pack(*insn) for insn in insns)


DROP_ALL = _INSN.pack(_RET_K, 0, 0, 0)
"""A program that drops every datagram (the sending socket reads nothing)."""


def attach(sock: socket.socket, program: bytes) -> bool:
    """Attach `program` to `sock`; False where the platform or the kernel refuses."""
    if not sys.platform.startswith("linux"):
        return False  # the option number means something else there, or nothing
    code = ctypes.create_string_buffer(program, len(program))
    fprog = _SockFprog(len(program) // _INSN.size, ctypes.addressof(code))
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, bytes(fprog))
    except OSError:
        return False
    return True


__all__ = ["DROP_ALL", "SKF_NET_OFF", "attach", "drop_source_program"]
