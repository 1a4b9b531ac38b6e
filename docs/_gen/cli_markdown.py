"""The ``mmsnap`` command line as Markdown, read from its argparse parser."""

from __future__ import annotations

import argparse
import re

from mmsnap_graph.app.cli import build_parser

_SPECIAL = re.compile(r"([\\*_<>\[\]|])")


def _text(s: str | None) -> str:
    """Help text as Markdown: `code` kept, other Markdown characters escaped."""
    if not s:
        return ""
    parts = " ".join(s.split()).split("`")
    return "`".join(p if i % 2 else _SPECIAL.sub(r"\\\1", p) for i, p in enumerate(parts))


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _sub_help(parser: argparse.ArgumentParser) -> dict[str, str]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return {a.dest: a.help for a in action._choices_actions}
    return {}


def _option_name(action: argparse.Action, formatter: argparse.HelpFormatter) -> str:
    if not action.option_strings:
        return formatter._metavar_formatter(action, action.dest)(1)[0]
    if action.nargs == 0:
        return ", ".join(action.option_strings)
    metavar = formatter._format_args(action, action.dest.upper())
    return ", ".join(f"{o} {metavar}" for o in action.option_strings)


def _actions(parser: argparse.ArgumentParser) -> list[str]:
    out = []
    formatter = parser._get_formatter()
    for group in parser._action_groups:
        actions = [a for a in group._group_actions
                   if a.help != argparse.SUPPRESS and not isinstance(a, (argparse._HelpAction,
                                                                         argparse._SubParsersAction))]
        if not actions:
            continue
        out += ["", f"**{_text(group.title)}**", ""]
        if group.description:
            out += [_text(group.description), ""]
        for action in actions:
            help_text = formatter._expand_help(action) if action.help else ""
            out.append(f"- `{_option_name(action, formatter)}`: {_text(help_text)}")
    return out


def _command(parser: argparse.ArgumentParser, name: str, level: int, summary: str | None
             ) -> list[str]:
    out = [f"{'#' * level} `{name}`", ""]
    if summary:
        out += [_text(summary), ""]
    if parser.description and parser.description != summary:
        out += [_text(parser.description), ""]
    out += ["```text", parser.format_usage().strip(), "```"]
    out += _actions(parser)
    if parser.epilog:
        out += ["", _text(parser.epilog)]
    out.append("")
    helps = _sub_help(parser)
    for sub, child in _subparsers(parser).items():
        out += _command(child, f"{name} {sub}", min(level + 1, 4), helps.get(sub))
    return out


def cli_reference() -> str:
    """The whole command line: one section per command, nested commands below."""
    parser = build_parser()
    head = ["# Command line", "",
            "Generated from the `mmsnap` parser when the site is built: each command's "
            "`mmsnap COMMAND --help` says the same. Degrees appear only here and in reports; "
            "the library speaks radians.", ""]
    return "\n".join(head + _command(parser, "mmsnap", 2, None))
