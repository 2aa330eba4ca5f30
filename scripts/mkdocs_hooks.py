"""MkDocs hook: the docstrings' Sphinx cross-reference roles read as plain code names on the API pages.

mkdocstrings renders ``:class:`~datagen.x.Y``` as the text ":class:" before a code span; this hook drops the role
and, for a ``~`` name, keeps only its last component (Sphinx's convention). Registered in ``mkdocs.yml``.
"""
from __future__ import annotations

import re

_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc|obj|const):(?=<code)")
_TILDE = re.compile(r"<code>~(?:[\w]+\.)*([\w]+)</code>")


def on_page_content(html: str, **kwargs) -> str:
    """The page's HTML with the roles removed (mkdocs event hook)."""
    return _TILDE.sub(r"<code>\1</code>", _ROLE.sub("", html))
