"""Range checks of values handed to the core from outside the wire: a restored state and
a starting sequence number.

A frame can only carry what fits its fields (`swarmd.core.wire`): a 16-bit epoch, a
16-bit robot id, a 48-bit sequence number. A restored epoch of
70000 would be accepted by the node, then fail in `wire.encode` on every frame that
carries it: a robot that never fences and a loop of tracebacks. So the node refuses such
values at construction (`NodeError`), and the state loader refuses them before (DESIGN
rule 2: a restarted robot with unusable state starts fresh).

Sans-IO and pure, like the rest of `swarmd.core`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

from swarmd.core.errors import NodeError
from swarmd.core.wire import KEY_LEN, SEQ_MAX

EPOCH_MAX = 0xFFFF
"""Epochs travel as 16-bit fields (HEARTBEAT, WARN, CLAIM, LEAVE bodies)."""
ROBOT_MAX = 0xFFFF
"""Robot ids travel as the 16-bit sender field."""


def _nonneg_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def restored_problems(
    known: Mapping[str, tuple[int, int]],
    held: tuple[str, int] | None,
    seq_start: int = 0,
) -> list[str]:
    """Why a restored state (and starting seq) cannot go on the wire: one phrase per
    problem, empty when it can. Holder 0 means "nobody" (a function with no holder).
    Entries about a function the plan no longer has are not a problem: the node ignores
    them (a swarm file edited between two runs)."""
    out: list[str] = []
    for f, pair in known.items():
        if not isinstance(pair, tuple | list) or len(pair) != 2:
            out.append(f"known[{f!r}] is not (holder, epoch)")
            continue
        holder, epoch = pair
        if not _nonneg_int(holder) or holder > ROBOT_MAX:
            out.append(f"known[{f!r}] holder {holder!r} is not in 0..{ROBOT_MAX} (16 bits)")
        if not _nonneg_int(epoch) or epoch > EPOCH_MAX:
            out.append(f"known[{f!r}] epoch {epoch!r} is not in 0..{EPOCH_MAX} (16 bits)")
    if held is not None:
        if not isinstance(held, tuple | list) or len(held) != 2:
            out.append(f"held {held!r} is not (function, epoch)")
        elif not _nonneg_int(held[1]) or held[1] > EPOCH_MAX:
            out.append(f"held epoch {held[1]!r} is not in 0..{EPOCH_MAX} (16 bits)")
    if not _nonneg_int(seq_start) or seq_start > SEQ_MAX:
        out.append(f"sequence number {seq_start!r} is not in 0..{SEQ_MAX} (48 bits)")
    return out


class _RestoredLike(Protocol):
    # `swarmd.core.records.Restored`.
    @property
    def known(self) -> Mapping[str, tuple[int, int]]: ...

    @property
    def held(self) -> tuple[str, int] | None: ...


def check_restored(restored: _RestoredLike | None, seq_start: int = 0) -> None:
    """Raise `NodeError` naming every problem of `restored_problems`; the node calls it
    at construction: `check_restored(restored, seq_start)`."""
    known = restored.known if restored is not None else {}
    held = restored.held if restored is not None else None
    problems = restored_problems(known, held, seq_start)
    if problems:
        raise NodeError("restored state out of range: " + "; ".join(problems))


def check_keys(keys: Sequence[bytes], *, signing: bool) -> tuple[bytes, ...]:
    """The swarm keys for a live reload (`Node.set_keys`), checked: each exactly
    `KEY_LEN` bytes, and not none at all while frames are signed (`signing`) — a config
    that lost its key lines would otherwise turn authentication off on a running robot,
    which then sends frames every keyed robot drops and accepts forged ones (DESIGN
    section 2); turning signing off takes a restart. Going from unsigned to signed is
    allowed: that cut-over has no window whichever way it is done. Raises `NodeError`."""
    new = tuple(keys)
    for i, key in enumerate(new):
        if not isinstance(key, bytes):
            raise NodeError(f"swarm key {i} is a {type(key).__name__}, not bytes")
        if len(key) != KEY_LEN:
            raise NodeError(f"swarm key {i} is {len(key)} bytes; a swarm key is "
                            f"exactly {KEY_LEN} bytes")
    if not new and signing:
        raise NodeError("no swarm key given while frames are signed; turning signing "
                        "off needs a restart, not a key reload")
    return new
