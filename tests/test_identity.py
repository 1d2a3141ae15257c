"""Per-robot identities (swarmd/base/identity.py): Ed25519 signer and keyring, key files,
`swarmd keygen --robot / --swarm`, the swarm file's `auth:` and the robot file's
`identity_file:`, the daemon's Identity and its SIGHUP reload (rotation, revocation)."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from swarms import PAPER, identity_file, paper_text, signed_paper
from typer.testing import CliRunner

import swarmd.daemon.daemon as daemon_mod
from sim.realtime.robotfiles import sign_for_run
from swarmd.base.identity import (
    Ed25519Signer,
    IdentityFileError,
    Keyring,
    generate_identity,
    public_key_of,
    read_key_file,
    read_private_key,
    read_public_keys,
    throwaway_identities,
    write_identity,
)
from swarmd.base.keys import load_key
from swarmd.cli import app
from swarmd.config import ConfigError, load_robot, load_swarm
from swarmd.core.auth import SIGNATURE_LEN, Identity

runner = CliRunner()


# -- signer and keyring ----------------------------------------------------------------------


def test_signature_verifies_for_its_robot_only() -> None:
    (priv1, pub1), (_, pub2) = generate_identity(), generate_identity()
    assert public_key_of(priv1) == pub1 and pub1 != pub2
    ring = Keyring({1: pub1, 2: pub2})
    sig = Ed25519Signer(1, priv1).sign(b"frame")
    assert len(sig) == SIGNATURE_LEN
    assert ring.verify(1, b"frame", sig)
    assert not ring.verify(2, b"frame", sig)           # robot 2 did not sign it
    assert not ring.verify(1, b"framf", sig)           # tampered
    assert not ring.verify(9, b"frame", sig)           # unknown robot
    assert not ring.verify(1, b"frame", sig[:-1])      # wrong length: False, no raise
    assert not ring.verify(1, b"frame", b"\0" * SIGNATURE_LEN)


def test_keyring_replace_rotates_and_revokes_in_place() -> None:
    (old, old_pub), (new, new_pub) = generate_identity(), generate_identity()
    ring = Keyring({3: old_pub})
    by_old, by_new = Ed25519Signer(3, old).sign(b"m"), Ed25519Signer(3, new).sign(b"m")
    ring.replace({3: [old_pub, new_pub]})              # the rotation window: both
    assert ring.verify(3, b"m", by_old) and ring.verify(3, b"m", by_new)
    ring.replace({3: new_pub})                         # window over
    assert not ring.verify(3, b"m", by_old) and ring.verify(3, b"m", by_new)
    ring.replace({3: new_pub}, revoked=[3])
    assert not ring.verify(3, b"m", by_new) and ring.robots == frozenset()
    with pytest.raises(ValueError, match="32 bytes"):
        ring.replace({3: b"short"})
    assert ring.revoked == {3}                         # a bad set leaves the old one


def test_keys_no_longer_in_force_verify_history_only() -> None:
    """A retired key and every key of a revoked robot verify a certificate's backers
    (`history=True`: DESIGN, "Key changes never rewrite history"), nothing else."""
    (old, old_pub), (new, new_pub) = generate_identity(), generate_identity()
    by_old, by_new = Ed25519Signer(3, old).sign(b"m"), Ed25519Signer(3, new).sign(b"m")
    ring = Keyring({3: new_pub}, retired={3: [old_pub]})
    assert not ring.verify(3, b"m", by_old) and ring.verify(3, b"m", by_old, history=True)
    assert ring.verify(3, b"m", by_new, history=True)
    ring.replace({3: new_pub}, revoked=[3], retired={3: [old_pub]})
    assert not ring.verify(3, b"m", by_new) and ring.verify(3, b"m", by_new, history=True)
    assert ring.verify(3, b"m", by_old, history=True)
    assert not ring.verify(3, b"n", by_new, history=True)  # still a signature check
    assert not ring.verify(9, b"m", by_new, history=True)  # unknown: no key at all


def test_signer_replace_signs_with_the_new_key() -> None:
    (a, a_pub), (b, b_pub) = generate_identity(), generate_identity()
    signer = Ed25519Signer(4, a)
    signer.replace(b)
    assert signer.public_key == b_pub
    assert Keyring({4: b_pub}).verify(4, b"x", signer.sign(b"x"))
    assert not Keyring({4: a_pub}).verify(4, b"x", signer.sign(b"x"))


def test_throwaway_identities_share_one_keyring() -> None:
    ids = throwaway_identities([1, 2, 3])
    assert set(ids) == {1, 2, 3}
    ring = ids[1].verifier
    for r, identity in ids.items():
        assert identity.verifier is ring and identity.signer.robot == r
        sig = identity.signer.sign(b"hello")
        assert ring.verify(r, b"hello", sig)
        assert not ring.verify(r % 3 + 1, b"hello", sig)


# -- key files -------------------------------------------------------------------------------


def test_write_identity_modes_and_round_trip(tmp_path: Path) -> None:
    key, pub = write_identity(tmp_path / "keys", 3)
    assert (key.name, pub.name) == ("robot-3.key", "robot-3.pub")
    assert stat.S_IMODE(key.stat().st_mode) == 0o600
    assert stat.S_IMODE(pub.stat().st_mode) == 0o644
    assert read_public_keys(pub) == (public_key_of(read_private_key(key)),)
    with pytest.raises(IdentityFileError, match="already exists; pass --force"):
        write_identity(tmp_path / "keys", 3)
    before = pub.read_bytes()
    write_identity(tmp_path / "keys", 3, force=True)
    assert pub.read_bytes() != before


@pytest.mark.parametrize("which", ["key", "pub"])
def test_write_identity_never_replaces_a_fifo_even_with_force(tmp_path: Path,
                                                              which: str) -> None:
    os.mkfifo(tmp_path / f"robot-2.{which}")
    with pytest.raises(IdentityFileError, match="is a FIFO, not a regular file; refusing"):
        write_identity(tmp_path, 2, force=True)
    assert stat.S_ISFIFO(os.lstat(tmp_path / f"robot-2.{which}").st_mode)
    other = "pub" if which == "key" else "key"
    assert not (tmp_path / f"robot-2.{other}").exists()  # nothing half-written
    assert not list(tmp_path.glob(".*.tmp"))


def test_private_key_readable_by_others_or_not_a_file_is_refused(tmp_path: Path) -> None:
    key, _ = write_identity(tmp_path, 1)
    key.chmod(0o640)
    with pytest.raises(IdentityFileError, match=r"mode 0640.*chmod 600"):
        read_private_key(key)
    fifo = tmp_path / "fifo.key"
    os.mkfifo(fifo)
    with pytest.raises(IdentityFileError, match="is a FIFO"):  # refused, not a hang
        read_private_key(fifo)
    bad = tmp_path / "bad.key"
    bad.write_text("not a key\n")
    bad.chmod(0o600)
    with pytest.raises(IdentityFileError, match="64 hex digits"):
        read_private_key(bad)


def test_public_key_file_lists_several_keys_with_comments(tmp_path: Path) -> None:
    (_, a), (_, b) = generate_identity(), generate_identity()
    path = tmp_path / "robot-1.pub"
    path.write_text(f"# rotation window\n{a.hex()}\n\n{b.hex()}  # new\n")
    assert read_public_keys(path) == (a, b)
    path.write_text("# nothing\n")
    with pytest.raises(IdentityFileError, match="empty"):
        read_public_keys(path)
    path.write_text("zz\n")
    with pytest.raises(IdentityFileError, match="hex digits"):
        read_public_keys(path)
    # A rotation's retired key: kept apart, for history only (docs/operations.md).
    path.write_text(f"{b.hex()}  # new\nretired\t{a.hex()}  # the old one\n")
    assert read_public_keys(path) == (b,) and read_key_file(path) == ((b,), (a,))
    path.write_text(f"retired {a.hex()}\n")
    assert read_key_file(path) == ((), (a,))
    with pytest.raises(IdentityFileError, match="only retired"):
        read_public_keys(path)
    path.write_text("retired\n")
    with pytest.raises(IdentityFileError, match="hex digits"):
        read_key_file(path)


# -- swarmd keygen ---------------------------------------------------------------------------


def test_keygen_robot_and_swarm(tmp_path: Path) -> None:
    result = runner.invoke(app, ["keygen", "--robot", "3", str(tmp_path / "k")])
    assert result.exit_code == 0, result.output
    assert {p.name for p in (tmp_path / "k").iterdir()} == {"robot-3.key", "robot-3.pub"}
    again = runner.invoke(app, ["keygen", "--robot", "3", str(tmp_path / "k")])
    assert again.exit_code == 1 and "already exists; pass --force" in again.output

    swarm = tmp_path / "paper.yaml"
    swarm.write_text(paper_text("{mode: per-robot, keys_dir: keys, revoked: [6]}"))
    result = runner.invoke(app, ["keygen", "--swarm", str(swarm), str(tmp_path / "keys")])
    assert result.exit_code == 0, result.output
    names = {p.name for p in (tmp_path / "keys").iterdir()}
    assert names == {f"robot-{r}.{ext}" for r in range(1, 6) for ext in ("key", "pub")}
    cfg = load_swarm(swarm)
    assert cfg.auth_mode == "per-robot" and cfg.revoked == {6}


def test_keygen_swarm_writes_nothing_when_one_file_is_in_the_way(tmp_path: Path) -> None:
    swarm = tmp_path / "paper.yaml"
    swarm.write_text(paper_text("{mode: per-robot, keys_dir: keys}"))
    (tmp_path / "keys").mkdir()
    os.mkfifo(tmp_path / "keys" / "robot-4.key")
    result = runner.invoke(app, ["keygen", "--swarm", str(swarm), str(tmp_path / "keys"),
                                 "--force"])
    assert result.exit_code == 1
    assert "robot-4.key is a FIFO, not a regular file" in " ".join(result.output.split())
    assert [p.name for p in (tmp_path / "keys").iterdir()] == ["robot-4.key"]


def test_keygen_shared_key_still_works_and_options_conflict(tmp_path: Path) -> None:
    result = runner.invoke(app, ["keygen", str(tmp_path / "swarm.key")])
    assert result.exit_code == 0, result.output
    assert len(load_key(tmp_path / "swarm.key")) == 32
    both = runner.invoke(app, ["keygen", "--robot", "1", "--swarm", str(PAPER), "x"])
    assert both.exit_code == 1 and "not both" in both.output


# -- config: auth section and identity_file --------------------------------------------------


def _robot(tmp_path: Path, robot: int, swarm: Path, extra: str = "") -> Path:
    # Only loaded, or refused by `swarmd start` before any socket: no port is opened.
    path = tmp_path / f"robot{robot}.yaml"
    path.write_text(f"robot: {robot}\nswarm: {swarm}\nstate_dir: {tmp_path / 'state'}\n"
                    f"transport: {{kind: udp}}\n{extra}")
    return path


def _one_error(path: Path) -> str:
    with pytest.raises(ConfigError) as info:
        load_robot(path)
    errors = info.value.errors
    assert len(errors) == 1, errors
    return str(errors[0])


def test_per_robot_robot_file_loads_with_its_key(tmp_path: Path) -> None:
    swarm, _ = signed_paper(tmp_path)
    cfg = load_robot(_robot(tmp_path, 2, swarm, "identity_file: keys/robot-2.key\n"))
    material = cfg.identity_material()
    assert material is not None and material.revoked == frozenset()
    assert public_key_of(material.private_key) in material.public_keys[2]
    assert set(material.public_keys) == {1, 2, 3, 4, 5, 6}


def test_per_robot_problems_name_file_and_field(tmp_path: Path) -> None:
    swarm, keys = signed_paper(tmp_path)
    # no identity_file
    msg = _one_error(_robot(tmp_path, 2, swarm))
    assert "robot2.yaml: identity_file:" in msg and "swarmd keygen --robot 2" in msg
    # another robot's key
    msg = _one_error(_robot(tmp_path, 2, swarm, "identity_file: keys/robot-3.key\n"))
    assert "identity_file:" in msg and "is not robot 2's key" in msg
    # readable by others
    identity_file(keys, 2).chmod(0o644)
    msg = _one_error(_robot(tmp_path, 2, swarm, "identity_file: keys/robot-2.key\n"))
    assert "identity_file:" in msg and "chmod 600" in msg
    identity_file(keys, 2).chmod(0o600)
    # a robot of the swarm without public key: the swarm file's field
    (keys / "robot-5.pub").unlink()
    msg = _one_error(_robot(tmp_path, 2, swarm, "identity_file: keys/robot-2.key\n"))
    assert msg.startswith(f"{swarm}: auth.keys_dir: robot 5: public key")
    assert "swarmd keygen --robot 5" in msg


def test_revoked_robot_needs_no_key_and_cannot_start(tmp_path: Path) -> None:
    swarm, keys = signed_paper(tmp_path)
    swarm.write_text(paper_text("{mode: per-robot, keys_dir: keys, revoked: [5]}"))
    (keys / "robot-5.pub").unlink()
    cfg = load_robot(_robot(tmp_path, 2, swarm, "identity_file: keys/robot-2.key\n"))
    material = cfg.identity_material()
    assert material is not None and 5 not in material.public_keys
    assert 5 not in material.retired  # no key left to verify its history with
    msg = _one_error(_robot(tmp_path, 5, swarm, "identity_file: keys/robot-5.key\n"))
    assert "robot 5 is revoked" in msg
    # Kept, a revoked robot's key verifies its history; a broken one is an error.
    write_identity(keys, 5, force=True)
    material = load_robot(_robot(tmp_path, 2, swarm, "identity_file: keys/robot-2.key\n"
                                 )).identity_material()
    assert material is not None and 5 not in material.public_keys
    assert material.retired[5] == read_public_keys(keys / "robot-5.pub")
    (keys / "robot-5.pub").write_text("garbage\n")
    msg = _one_error(_robot(tmp_path, 2, swarm, "identity_file: keys/robot-2.key\n"))
    assert "auth.keys_dir: revoked robot 5: public key" in msg


def test_start_refuses_an_unsigned_swarm_that_does_not_say_so(tmp_path: Path) -> None:
    swarm = tmp_path / "paper.yaml"
    swarm.write_text(paper_text("key_file: null"))
    robot = _robot(tmp_path, 2, swarm)
    msg = _one_error(robot)
    assert "auth: the swarm is unsigned and does not say so" in msg
    assert "write `auth: none`" in msg
    proc = subprocess.run([sys.executable, "-m", "swarmd.cli", "start", "-c", str(robot)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert len(proc.stdout.strip().splitlines()) == 1, proc.stdout  # one line, what to do
    swarm.write_text(paper_text("none"))
    assert load_robot(robot).swarm.auth_mode == "none"


@pytest.mark.parametrize(("auth", "field", "message"), [
    ("shout", "auth", "must be `none` or a mapping"),
    ("{mode: per-robot, keys: x}", "auth.per-robot.keys", "did you mean 'keys_dir'"),
    ("{mode: shared}", "auth.shared.key_file", "required field is missing"),
])
def test_bad_auth_section(tmp_path: Path, auth: str, field: str, message: str) -> None:
    swarm = tmp_path / "paper.yaml"
    swarm.write_text(paper_text(auth))
    with pytest.raises(ConfigError) as info:
        load_swarm(swarm)
    assert [(p.field, message in p.message) for p in info.value.errors] == [(field, True)]


def test_shared_mode_under_auth_or_at_top_level(tmp_path: Path) -> None:
    write = tmp_path / "swarm.key"
    runner.invoke(app, ["keygen", str(write)])
    for text in (paper_text("{mode: shared, key_file: swarm.key}"),
                 paper_text("key_file: swarm.key")):
        (tmp_path / "s.yaml").write_text(text)
        cfg = load_swarm(tmp_path / "s.yaml")
        assert cfg.auth_mode == "shared" and cfg.key() == load_key(write)
    (tmp_path / "s.yaml").write_text(paper_text("none") + "key_file: swarm.key\n")
    with pytest.raises(ConfigError, match="both `auth` and `key_file`"):
        load_swarm(tmp_path / "s.yaml")


# -- the daemon ------------------------------------------------------------------------------


async def test_daemon_gives_the_node_its_identity_and_sighup_reloads_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from test_runtime import launch

    swarm, keys = signed_paper(tmp_path)
    robot = _robot(tmp_path, 1, swarm, "identity_file: keys/robot-1.key\nlink: {kind: none}\n")
    given: list[object] = []
    from swarmd.core.node import Node as real_node

    def spy(*args: object, **kwargs: object) -> object:
        given.append(kwargs.get("identity"))
        return real_node(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(daemon_mod, "Node", spy)
    running = await launch(load_robot(robot), config_path=robot)
    try:
        d = running.daemon
        assert d is not None and d.keyring is not None and d.signer is not None
        (identity,) = given
        assert isinstance(identity, Identity)
        assert identity.signer is d.signer and identity.verifier is d.keyring
        ring = d.keyring
        assert ring.verify(1, b"m", d.signer.sign(b"m"))

        # Rotation of robot 3: its new public key replaces the old, then SIGHUP.
        old3 = Ed25519Signer(3, read_private_key(identity_file(keys, 3)))
        write_identity(keys, 3, force=True)
        new3 = Ed25519Signer(3, read_private_key(identity_file(keys, 3)))
        assert ring.verify(3, b"m", old3.sign(b"m"))
        d.reload()
        assert not ring.verify(3, b"m", old3.sign(b"m"))
        assert ring.verify(3, b"m", new3.sign(b"m"))

        # This robot's own key rotated: the signer the node holds signs with the new one.
        write_identity(keys, 1, force=True)
        d.reload()
        assert d.signer.public_key == read_public_keys(keys / "robot-1.pub")[0]
        assert ring.verify(1, b"m", d.signer.sign(b"m"))

        # Revocation of robot 4.
        four = Ed25519Signer(4, read_private_key(identity_file(keys, 4)))
        swarm.write_text(paper_text("{mode: per-robot, keys_dir: keys, revoked: [4]}"))
        d.reload()
        assert ring.revoked == {4} and not ring.verify(4, b"m", four.sign(b"m"))
        # What it signed stays history (its .pub is kept), as do robot 3's retired key's.
        assert ring.verify(4, b"m", four.sign(b"m"), history=True)
        pub3 = keys / "robot-3.pub"
        pub3.write_text(pub3.read_text() + f"retired {old3.public_key.hex()}\n")
        d.reload()
        assert not ring.verify(3, b"m", old3.sign(b"m"))
        assert ring.verify(3, b"m", old3.sign(b"m"), history=True)

        # A broken keys dir is refused: the keys in use stay.
        (keys / "robot-5.pub").write_text("garbage\n")
        errors = d.reload_errors
        d.reload()
        assert d.reload_errors == errors + 1
        assert ring.verify(3, b"m", new3.sign(b"m")) and ring.revoked == {4}
    finally:
        assert await running.finish() == 0


@pytest.mark.slow
def test_swarmd_start_per_robot_reloads_keys_on_sighup(tmp_path: Path) -> None:
    from test_start import lines_of, start, wait_line

    swarm, _ = signed_paper(tmp_path)
    robot = _robot(tmp_path, 2, swarm, "identity_file: keys/robot-2.key\n")
    proc = start(robot)
    try:
        assert proc.stdout is not None
        q = lines_of(proc.stdout)
        seen: list[dict[str, object]] = []
        started = wait_line(q, seen, "starting", timeout=30)
        assert (started["auth"], started["signed"]) == ("per-robot", True)
        wait_line(q, seen, "ready", timeout=30)
        swarm.write_text(paper_text("{mode: per-robot, keys_dir: keys, revoked: [6]}"))
        proc.send_signal(signal.SIGHUP)
        reloaded = wait_line(q, seen, "SIGHUP: identity keys reloaded", timeout=30)
        assert reloaded["revoked"] == [6] and 6 not in reloaded["robots"]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=30)
    assert proc.returncode == 0


# -- swarmd sim: a throwaway key set per run -------------------------------------------------


def test_sim_signs_each_run_with_throwaway_keys(tmp_path: Path) -> None:
    copy, files = sign_for_run(tmp_path / "run", PAPER)
    cfg = load_swarm(copy)
    assert cfg.auth_mode == "per-robot" and cfg.keys_dir_path == tmp_path / "run" / "keys"
    assert set(files) == {1, 2, 3, 4, 5, 6}
    for r, path in files.items():
        assert public_key_of(read_private_key(path)) in read_public_keys(
            tmp_path / "run" / "keys" / f"robot-{r}.pub")
    _, files2 = sign_for_run(tmp_path / "run2", PAPER)
    assert read_private_key(files[1]) != read_private_key(files2[1])  # per run

    unsigned = tmp_path / "none.yaml"
    unsigned.write_text(paper_text("none"))
    assert sign_for_run(tmp_path / "run3", unsigned) == (unsigned, {})

    (tmp_path / "swarm.key").write_bytes(b"k" * 32)
    (tmp_path / "swarm.key").chmod(0o600)
    shared = tmp_path / "shared.yaml"
    shared.write_text(paper_text("{mode: shared, key_file: swarm.key}"))
    copy, files = sign_for_run(tmp_path / "run4", shared)
    cfg = load_swarm(copy)
    assert files == {} and cfg.auth_mode == "shared"
    assert cfg.key() not in (None, b"k" * 32)  # a throwaway key, not the real one


def test_a_small_serial_radio_carries_signed_frames_in_fragments(tmp_path: Path) -> None:
    # Per-robot signed frames (CERT: 92 B) exceed a 64 B serial frame and go out in
    # fragments (transport/fragment.py): the default radio serves; below 24 B a fragment
    # would have no room, so that is refused.
    from swarmd.config import ConfigError, load_robot

    swarm, keys = signed_paper(tmp_path)
    robot = tmp_path / "robot.yaml"
    head = f"robot: 2\nswarm: {swarm}\nidentity_file: {identity_file(keys, 2)}\n"
    robot.write_text(head + "transport: {kind: serial, port: /dev/ttyUSB0}\n")
    assert load_robot(robot).transport.max_payload == 64  # type: ignore[union-attr]
    robot.write_text(head + "transport: {kind: serial, port: /dev/ttyUSB0, max_payload: 23}\n")
    with pytest.raises(ConfigError, match="max_payload"):
        load_robot(robot)
    robot.write_text(head + "transport: {kind: serial, port: /dev/ttyUSB0, max_payload: 93}\n")
    assert load_robot(robot).transport.max_payload == 93  # type: ignore[union-attr]
