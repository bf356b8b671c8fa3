"""Command-line helpers shared by the scripts (ROS-free)."""
from __future__ import annotations

import argparse
import inspect
import re


def help_text(doc: str) -> str:
    """A docstring as a script's ``--help`` text: all of it, not its first line (which may end
    mid-sentence), its indentation removed and its reST markup (````x````, ``:mod:`x```) plain."""
    text = inspect.cleandoc(doc or '')
    text = re.sub(r':[a-z]+:`([^`]*)`', r'\1', text)
    return text.replace('``', '')


def parser(prog: str, doc: str, **kw) -> argparse.ArgumentParser:
    """An ArgumentParser whose description is ``help_text(doc)`` with its line breaks kept
    (usage lines and examples stay as written)."""
    return argparse.ArgumentParser(prog=prog, description=help_text(doc),
                                   formatter_class=argparse.RawDescriptionHelpFormatter, **kw)
