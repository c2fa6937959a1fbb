"""Help text for the CLI's flags from the ``Config``/``Hyperparams`` dataclasses: each field's
docstring (a string after it), trailing comment, or comment above.

Why not tyro, which does the same: the flags here are built from a dataclass *instance* (the
algorithm's recipe for one env, with the script's overrides), so ``--help`` shows the values a
run of that script would use; the parser and the user errors are the project's own one-line
``OneLineParser``; and the learners document their fields with trailing comments, which this
reads in ~50 lines without a dependency.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import io
import textwrap
import tokenize
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from _typeshed import DataclassInstance


def _comments(source: str) -> dict[int, str]:
    """Line number -> text of the ``#`` comment on that line."""
    comments = {}
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            comments[token.start[0]] = token.string.lstrip("#").strip()
    return comments


def _class_field_docs(cls: type) -> dict[str, str]:
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    definition = ast.parse(source).body[0]
    if not isinstance(definition, ast.ClassDef):
        return {}
    body = definition.body
    comments, lines = _comments(source), source.splitlines()
    docs = {}
    for index, node in enumerate(body):
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        following = body[index + 1] if index + 1 < len(body) else None
        if (
            isinstance(following, ast.Expr)
            and isinstance(following.value, ast.Constant)
            and isinstance(following.value.value, str)
        ):
            docs[node.target.id] = inspect.cleandoc(following.value.value)
        elif node.end_lineno in comments:
            docs[node.target.id] = comments[node.end_lineno]
        else:
            above: list[str] = []
            line = node.lineno - 1
            while line in comments and lines[line - 1].lstrip().startswith("#"):
                above.insert(0, comments[line])
                line -= 1
            if above:
                docs[node.target.id] = " ".join(above)
    return docs


def field_docs(cls: type) -> dict[str, str]:
    """Each dataclass field's docstring (string after it), trailing comment, or comment above."""
    docs: dict[str, str] = {}
    for base in reversed(cls.__mro__):
        if dataclasses.is_dataclass(base):
            docs.update(_class_field_docs(base))
    return docs


def undocumented_fields(instance: DataclassInstance) -> list[str]:
    """Fields that would get no help text (a test keeps this empty for every algorithm)."""
    docs = field_docs(type(instance))
    return [f.name for f in dataclasses.fields(instance) if not docs.get(f.name)]
