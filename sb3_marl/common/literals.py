"""Strings of hyperparameters as data, never as code (``-params`` values, a YAML
``policy_kwargs: "dict(...)"``): :func:`parse_literal` accepts numbers, strings, lists, tuples,
dicts, ``dict(key=...)`` and the names of :data:`ALLOWED_NAMES` (activation functions,
optimisers); anything else is refused (rl-zoo evaluates these strings)."""

from __future__ import annotations

import ast
import re
from typing import Any

from torch import nn, optim

#: Names a hyperparameter string may use (``policy_kwargs: "dict(activation_fn=nn.Tanh)"``),
#: under the spellings rl-zoo's configs use.
ALLOWED_NAMES: dict[str, Any] = {
    **{
        f"{prefix}{name}": getattr(nn, name)
        for prefix in ("nn.", "th.nn.", "torch.nn.", "")
        for name in ("ReLU", "Tanh", "ELU", "LeakyReLU", "SiLU", "GELU", "Sigmoid", "Identity")
    },
    **{
        f"{prefix}{name}": getattr(optim, name)
        for prefix in ("optim.", "th.optim.", "torch.optim.", "")
        for name in ("Adam", "AdamW", "RMSprop", "SGD")
    },
    "True": True,
    "False": False,
    "None": None,
    "inf": float("inf"),
    "nan": float("nan"),
}
#: rl-zoo's schedule strings, kept as strings for its schedule parser: ``lin_5e-4``.
SCHEDULE = re.compile(r"^lin_[0-9.eE+-]+$")


def parse_literal(text: str, key: str) -> Any:
    """The value of ``key:text`` (a ``-params`` item or a YAML string meant as Python).

    Numbers, strings, lists, tuples, dicts, ``dict(key=value, ...)`` and :data:`ALLOWED_NAMES`;
    a schedule ``lin_<x>`` or a bare word (``global``, ``local``) stays a string. Anything else
    (calls, attributes, operators) is refused: a ValueError naming ``key``.
    """
    text = text.strip()
    if SCHEDULE.match(text):
        return text
    try:
        tree = ast.parse(text, mode="eval").body
    except SyntaxError:
        if re.fullmatch(r"[\w.\-/]*", text):
            return text  # a bare word rl-zoo would keep as a string (e.g. a Python keyword: global)
        raise ValueError(
            f"Invalid value for {key}: {text!r} is not a literal (numbers, strings, lists, dicts, dict(...))."
        ) from None
    if isinstance(tree, ast.Name) and tree.id not in ALLOWED_NAMES:
        return text  # a bare word (reward_mode:local)
    if re.fullmatch(r"[A-Za-z_][\w]*(-[A-Za-z_\w]+)+", text):
        return text  # a hyphenated bare word (prior:idm-mobil), not a subtraction of names
    try:
        return _literal(tree)
    except ValueError as error:
        if isinstance(tree, ast.Dict) and any(isinstance(k, ast.Name) for k in tree.keys):
            raise ValueError(
                f"Invalid value for {key}: {text!r}: a mapping's keys are quoted strings, as in Python: "
                "{'comfort': False} or dict(comfort=False)."
            ) from None
        raise ValueError(
            f"Invalid value for {key}: {text!r}: {error} (it would run code). Allowed: numbers, strings, "
            "lists, tuples, dicts, dict(key=value, ...) and the names "
            f"{sorted(n for n in ALLOWED_NAMES if n.startswith(('nn.', 'th.optim.')))}."
        ) from None


def _literal(node: ast.AST) -> Any:
    if isinstance(node, ast.Constant):
        return node.value
    if (
        isinstance(node, ast.UnaryOp)
        and isinstance(node.op, (ast.USub, ast.UAdd))
        and isinstance(node.operand, ast.Constant)
        and isinstance(node.operand.value, (int, float))
        and not isinstance(node.operand.value, bool)
    ):
        return -node.operand.value if isinstance(node.op, ast.USub) else node.operand.value
    if isinstance(node, ast.List):
        return [_literal(e) for e in node.elts]
    if isinstance(node, ast.Tuple):
        return tuple(_literal(e) for e in node.elts)
    if isinstance(node, ast.Dict):
        if any(k is None for k in node.keys):
            raise ValueError("** unpacking is not a literal")
        return {_literal(k): _literal(v) for k, v in zip(node.keys, node.values)}  # type: ignore[arg-type]
    if (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id == "dict"
        and not node.args
        and all(k.arg is not None for k in node.keywords)
    ):
        return {k.arg: _literal(k.value) for k in node.keywords}
    name = ast.unparse(node)
    if isinstance(node, (ast.Name, ast.Attribute)) and name in ALLOWED_NAMES:
        return ALLOWED_NAMES[name]
    kind = (
        "a call"
        if isinstance(node, ast.Call)
        else "an operator"
        if isinstance(node, (ast.BinOp, ast.BoolOp))
        else "a name"
        if isinstance(node, (ast.Name, ast.Attribute))
        else "an expression"
    )
    raise ValueError(f"{kind} ({name}) is not a literal")


__all__ = ["ALLOWED_NAMES", "SCHEDULE", "parse_literal"]
