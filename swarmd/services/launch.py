"""Import the paper's ROS launch file (its appendix, "Defining a swarm") as a swarm file.

The launch file has one `<node>` per robot with `<param>`s `robot_id`, `state`
(`active` / `inactive`), `neighbors` (active robots, e.g. " [2,4]") and `subs`
(inactive robots, the active robots they may substitute). The same swarm written as a
ROS 2 launch file reads the same way: ROS 2 XML (`<node pkg= exec=>`, nodes possibly in
`<group>`s) through the one XML path, ROS 2 YAML (`launch: [- node: {param: [{name:,
value:}]}]`, `group: {children: [...]}`) through `parse_yaml_launch`. Python launch
files run code and are not read. DESIGN.md section 3: active
robot R gets the function `fR`, a formation slot; neighbours and subs carry over; the
timing is the `udp()` preset. Slots are laid out on a circle (radius 2 m at 1.5 m,
so the paper's four robots sit 2.8 m apart) and homes in a row on the ground beside
it; both are only starting points for the MuJoCo sim.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from swarmd.base.files import read_regular_file

SLOT_RADIUS = 2.0
"""m. Radius of the circle the imported formation slots are placed on."""
SLOT_HEIGHT = 1.5
"""m. Flight altitude of the slots."""
HOME_SPACING = 1.0
"""m. Distance between neighbouring homes in the parking row."""
HOME_Y = -3.5
"""m. The parking row lies outside the circle so take-off paths do not cross slots."""

_IDS = r"(\d+(\s*,\s*\d+)*)?"
_ID_LIST = re.compile(rf"^(\[\s*{_IDS}\s*\]|{_IDS})$")


class LaunchError(ValueError):
    """A launch file that cannot be imported; the message names file and node."""


@dataclass(frozen=True, slots=True)
class LaunchRobot:
    """One `<node>` of the launch file."""

    robot_id: int
    state: str
    """`active` or `standby` (the paper's `inactive`)."""
    neighbors: tuple[int, ...]
    subs: tuple[int, ...]


def parse_launch(text: str, name: str = "<launch>") -> list[LaunchRobot]:
    """The robots of a launch file (ROS 1 or ROS 2 XML, ROS 2 YAML), in file order.
    Raises LaunchError."""
    if name.endswith(".py"):
        raise LaunchError(f"{name}: a Python launch file runs code and is not read; write "
                          "the swarm as a ROS 2 XML or YAML launch file")
    if not text.lstrip().startswith("<"):
        return parse_yaml_launch(text, name)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        line, col = exc.position
        raise LaunchError(f"{name}: line {line}, column {col}: malformed XML: {exc}") from None
    if root.tag != "launch":
        raise LaunchError(f"{name}: the root element is <{root.tag}>, expected <launch>")
    robots: list[LaunchRobot] = []
    for index, node in enumerate(root.iter("node")):
        label = f"{name}: node[{index}]" + (
            f" (name={node.get('name')!r})" if node.get("name") else ""
        )
        params: dict[str, str] = {}
        for p in node.iter("param"):
            key, value = p.get("name"), p.get("value")
            if key is None or value is None:
                raise LaunchError(f"{label}: <param> needs both name and value attributes")
            _add_param(params, key, value, label)
        robots.append(_robot(params, label))
    if not robots:
        raise LaunchError(f"{name}: no <node> elements: nothing to import")
    return robots


def parse_yaml_launch(text: str, name: str = "<launch>") -> list[LaunchRobot]:
    """The robots of a ROS 2 YAML launch file, in file order. Raises LaunchError."""
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        raise LaunchError(f"{name}: {where}malformed launch file (neither XML nor YAML): "
                          f"{getattr(exc, 'problem', None) or exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("launch"), list):
        raise LaunchError(f"{name}: a YAML launch file is a mapping with a `launch:` list")
    nodes: list[Any] = []
    _yaml_nodes(doc["launch"], nodes, name)
    robots: list[LaunchRobot] = []
    for index, node in enumerate(nodes):
        label = f"{name}: node[{index}]" + (
            f" (name={node.get('name')!r})" if node.get("name") else "")
        params: dict[str, str] = {}
        entries = node.get("param", [])
        if not isinstance(entries, list):
            raise LaunchError(f"{label}: param must be a list of {{name, value}}")
        for p in entries:
            if not isinstance(p, dict) or "name" not in p or "value" not in p:
                raise LaunchError(f"{label}: each param needs a name and a value")
            key = str(p["name"])
            _add_param(params, key, _yaml_value(p["value"], label, key), label)
        robots.append(_robot(params, label))
    if not robots:
        raise LaunchError(f"{name}: no `node` entries: nothing to import")
    return robots


def _add_param(params: dict[str, str], key: str, value: str, label: str) -> None:
    """One node's param, as either launch format gives it: a substitution (`$(...)`)
    would need ROS's launch system to evaluate, and a param given twice is one ROS takes
    the last of (a silent surprise): both are refused."""
    if "$(" in value:
        raise LaunchError(f"{label}: param {key}: substitutions ({value!r}) are not "
                          "supported; write the value out")
    if key in params:
        raise LaunchError(f"{label}: param {key} is given twice "
                          f"({params[key]!r} and {value!r})")
    params[key] = value


def _yaml_nodes(entries: list[Any], out: list[Any], name: str) -> None:
    """The `node` mappings of a YAML launch list, groups opened, in file order."""
    for entry in entries:
        if not isinstance(entry, dict):
            continue
        node = entry.get("node")
        if isinstance(node, dict):
            out.append(node)
        group = entry.get("group")
        if isinstance(group, dict) and isinstance(group.get("children"), list):
            _yaml_nodes(group["children"], out, name)


def _yaml_value(value: Any, label: str, key: str) -> str:
    """A typed YAML param value in the launch XML's text form (`[2,4]`, `1`)."""
    if isinstance(value, bool) or value is None or isinstance(value, dict | float):
        raise LaunchError(f"{label}: param {key}: {value!r} is not a robot id, a list of "
                          "robot ids or a state")
    if isinstance(value, list):
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise LaunchError(f"{label}: param {key}: {value!r} is not a list of robot ids")
        return "[" + ",".join(str(v) for v in value) + "]"
    return str(value)


def _robot(params: dict[str, str], label: str) -> LaunchRobot:
    if "robot_id" not in params:
        raise LaunchError(f"{label}: missing param robot_id")
    raw_id = params["robot_id"].strip()
    if not raw_id.isdigit() or not 1 <= int(raw_id) <= 0xFFFF:
        raise LaunchError(f"{label}: param robot_id: {raw_id!r} is not a robot id (1..65535)")
    state = params.get("state", "active").strip().lower()
    if state not in ("active", "inactive", "standby"):
        raise LaunchError(f"{label}: param state: {state!r} is neither active nor inactive")
    return LaunchRobot(
        robot_id=int(raw_id),
        state="active" if state == "active" else "standby",
        neighbors=_ids(params.get("neighbors", ""), label, "neighbors"),
        subs=_ids(params.get("subs", ""), label, "subs"),
    )


def _ids(value: str, label: str, what: str) -> tuple[int, ...]:
    """Parse the paper's list syntax " [2,4]" (brackets optional, empty allowed)."""
    text = value.strip()
    if not _ID_LIST.match(text):
        raise LaunchError(f"{label}: param {what}: {value!r} is not a list of robot ids "
                          "like [2,4]")
    return tuple(int(x) for x in re.findall(r"\d+", text))


def launch_to_swarm(
    robots: list[LaunchRobot], *, swarm_id: int = 1543, name: str = "imported"
) -> dict[str, Any]:
    """The swarm file (as plain data) for the launch file's robots."""
    active = [r for r in robots if r.state == "active"]
    functions: dict[str, Any] = {}
    for k, r in enumerate(active):
        angle = 2 * math.pi * k / len(active)
        functions[f"f{r.robot_id}"] = {
            "kind": "slot",
            "position": [
                _r(SLOT_RADIUS * math.cos(angle)),
                _r(SLOT_RADIUS * math.sin(angle)),
                SLOT_HEIGHT,
            ],
        }
    entries: list[dict[str, Any]] = []
    ordered = sorted(robots, key=lambda r: r.robot_id)
    for k, r in enumerate(ordered):
        entry: dict[str, Any] = {"id": r.robot_id, "state": r.state}
        if r.state == "active":
            entry["function"] = f"f{r.robot_id}"
        if r.neighbors:
            entry["neighbors"] = list(r.neighbors)
        if r.subs:
            entry["subs"] = list(r.subs)
        entry["home"] = [_r(HOME_SPACING * (k - (len(ordered) - 1) / 2)), HOME_Y]
        entries.append(entry)
    return {
        "swarm": {"id": swarm_id, "name": name},
        "timing": {"preset": "udp"},
        "auth": {"mode": "per-robot", "keys_dir": "keys"},
        "functions": functions,
        "robots": entries,
        "alert_hook": None,
    }


def _r(x: float) -> float:
    # Round away float noise (2 cos(pi/2) = 1.2e-16) so the YAML stays readable.
    return round(x, 3) + 0.0


def swarm_yaml(data: dict[str, Any], origin: str) -> str:
    """YAML text of a swarm file, with a header saying where it came from."""
    body = yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
    return f"# Generated by `swarmd import-launch` from {origin}.\n{body}"


MAX_LAUNCH_BYTES = 8 * 1024 * 1024
"""About 150 bytes of XML per robot: room for any swarm; a bigger file is the wrong one."""


def import_launch_file(
    path: Path, *, swarm_id: int = 1543, name: str | None = None
) -> str:
    """Read a launch file and return the swarm YAML. Raises LaunchError, OSError
    (`swarmd.base.files.FileRefused` for a FIFO, device or directory, or above 8 MiB),
    UnicodeDecodeError."""
    text = read_regular_file(path, MAX_LAUNCH_BYTES).decode("utf-8")
    robots = parse_launch(text, str(path))
    # ROS 2 names its launch files `x.launch.xml` / `x.launch.yaml`: the swarm is `x`.
    data = launch_to_swarm(robots, swarm_id=swarm_id,
                           name=name or path.stem.removesuffix(".launch"))
    return swarm_yaml(data, path.name)
