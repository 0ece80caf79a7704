"""Generated blocks inside a hand-written or generated Markdown file, between ``<!-- NAME -->`` and
``<!-- /NAME -->``: a command rewrites the block and a test compares it with what the generator makes, so the
text around it can stay hand-written while the block cannot go stale.
"""

from __future__ import annotations

import re


def _pattern(name: str) -> re.Pattern[str]:
    return re.compile(rf"<!-- {re.escape(name)} -->\n.*?<!-- /{re.escape(name)} -->\n*", re.DOTALL)


def get_block(text: str, name: str) -> str | None:
    """The body of block ``name`` in ``text`` (without its markers); None when there is none."""
    match = _pattern(name).search(text)
    if match is None:
        return None
    body = match.group(0)[len(f"<!-- {name} -->\n") :].rstrip("\n")
    return body[: -len(f"<!-- /{name} -->")].rstrip("\n")


def put_block(text: str, name: str, body: str | None, after_title: bool = False) -> str:
    """``text`` with block ``name`` holding ``body``: in place of the old block, else at the top (after a
    ``# title`` line when ``after_title``); ``body`` None takes the block out."""
    pattern = _pattern(name)
    block = "" if body is None else f"<!-- {name} -->\n{body.rstrip()}\n<!-- /{name} -->\n\n"
    if pattern.search(text):
        return pattern.sub(lambda _: block, text, count=1)
    if body is None:
        return text
    if after_title and text.startswith("# "):
        title, _, rest = text.partition("\n")
        return f"{title}\n\n{block}{rest.lstrip(chr(10))}"
    return block + text
