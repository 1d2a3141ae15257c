"""DESIGN section 2, "Where the rules live": `Node` is a stack of layers, each class on
the one below, each calling only methods defined in itself or below. No method is
declared low only to be defined higher up (a stub), so a reader follows any call down,
never up, and the takeover episode reads in one module (`episode.py`)."""

from __future__ import annotations

import ast
import inspect
import textwrap

from swarmd.core.node import Node


def layers(top: type) -> list[type]:
    """`top` and the classes below it, top first."""
    return [c for c in top.__mro__ if c is not object]


def _methods(cls: type) -> dict[str, ast.FunctionDef]:
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0]
    assert isinstance(body, ast.ClassDef)
    return {f.name: f for f in body.body if isinstance(f, ast.FunctionDef)}


def upward_calls(top: type) -> list[str]:
    """Every `self.name` a layer uses that is a method of a layer above it, as
    `Class.method -> name`."""
    stack = layers(top)
    defined = [set(_methods(c)) for c in stack]
    out = []
    for i, cls in enumerate(stack):
        above = set().union(*defined[:i]) - set().union(*defined[i:])
        for name, fn in _methods(cls).items():
            used = {n.attr for n in ast.walk(fn) if isinstance(n, ast.Attribute)
                    and isinstance(n.value, ast.Name) and n.value.id == "self"}
            out += [f"{cls.__name__}.{name} -> {u}" for u in sorted(used & above)]
    return out


def stubs(top: type) -> list[str]:
    """Methods whose whole body raises `NotImplementedError`: a declaration made for a
    layer above to fill in."""
    out = []
    for cls in layers(top):
        for name, fn in _methods(cls).items():
            body = [s for s in fn.body if not (isinstance(s, ast.Expr)
                                               and isinstance(s.value, ast.Constant))]
            if len(body) == 1 and isinstance(body[0], ast.Raise) \
                    and "NotImplementedError" in ast.unparse(body[0]):
                out.append(f"{cls.__name__}.{name}")
    return out


def test_node_is_a_stack_of_layers_one_on_the_next() -> None:
    names = [c.__name__ for c in layers(Node)]
    assert names == ["Node", "Restart", "Hearing", "Episode", "Proofs", "Views",
                     "NodeBase"]
    assert all(len(c.__bases__) == 1 for c in layers(Node))


def test_every_layer_calls_only_itself_and_below() -> None:
    assert upward_calls(Node) == []


def test_no_method_is_a_stub_for_a_layer_above() -> None:
    assert stubs(Node) == []


class _Low:
    def _a(self) -> None:
        self._b()

    def _b(self) -> None:
        raise NotImplementedError

    def _c(self) -> None:
        self._d()  # type: ignore[attr-defined]  # mypy refuses it too


class _High(_Low):
    def _b(self) -> None:
        pass

    def _d(self) -> None:
        pass


def test_the_checks_find_an_upward_call_and_a_stub() -> None:
    # `_a` calls `_b` through a stub below (the stub is reported: it exists only for
    # the layer above); `_c` calls `_d`, defined only above (an upward call).
    assert stubs(_High) == ["_Low._b"]
    assert upward_calls(_High) == ["_Low._c -> _d"]
