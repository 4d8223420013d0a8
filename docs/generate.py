"""Write the generated parts of the documentation into its committed Markdown:
``python docs/generate.py`` (``--check``: list the stale pages and exit 1, write nothing).

The pages are read in two places, the built site (Sphinx + MyST) and the repository page (GitHub
renders the Markdown as it is), so what firmtool can say about itself (the scenario reference,
each command's help, the command table, the ``firmtool init`` templates, the figures and their
commands, the tutorials' code, the README's first part on the site's front page) is written into
the pages between two HTML comments, which both renderers hide::

    <!-- generated: help run -->
    ...text this script writes...
    <!-- end generated -->

The first comment names the block: ``help COMMAND``, ``commands``, ``template ROBOT``,
``scenario-reference``, ``figures``, ``api ENTRIES`` (the API reference from the docstrings:
``docs/api_markdown.py``), ``results NAME...`` (the measured numbers of ``docs/results/numbers.json``:
``docs/results_numbers.py``), ``readme`` (the README up to its ``## Documentation``, with
its links made relative to docs/) or ``include PATH [pyobject=NAME] [start-at=TEXT]
[end-before=TEXT] [language=LANG]`` (a file's text as a code block, ``PATH`` relative to the page,
with a link to the file). ``tests/test_generated_docs.py`` fails when a page differs from what this
script writes, so that a change of the code shows in the pages of the same commit.

Written here rather than with a Sphinx directive or ``literalinclude`` because those render only
in the built site: on the repository page they are empty.
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import inspect
import re
import shlex
import sys
from pathlib import Path

import typer

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
# The checkout documents itself, even where another version of firmtool is installed (as docs/conf.py).
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(DOCS))

import api_markdown  # noqa: E402  (docs/api_markdown.py: the API reference as Markdown)
import results_numbers  # noqa: E402  (docs/results_numbers.py: the results pages' measured numbers)

from firmtool.cli import app  # noqa: E402
from firmtool.scenario.docs import md_escape, reference_markdown, template  # noqa: E402

BLOCK = re.compile(r"(<!-- generated: (?P<spec>[^\n]*?) -->\n)(?P<body>.*?)(<!-- end generated -->)", re.S)


class GenerateError(Exception):
    """A block this script cannot write (an unknown command, a missing file or page)."""


# ---------------------------------------------------------------------------------------------------
# command help, from the command line's own definitions

def _commands() -> dict:
    """The command line's click commands by name."""
    return dict(typer.main.get_command(app).commands)


def _metavar(cmd, param) -> str:
    """The kind of value an option takes, from the command function's annotation (typer's own
    parameter classes differ between its versions)."""
    annotation = str(inspect.signature(cmd.callback).parameters[param.name].annotation)
    for word, metavar in (("Path", "PATH"), ("list", "TEXT"), ("float", "NUMBER"), ("int", "INTEGER"),
                          ("str", "TEXT")):
        if word in annotation:
            return metavar
    return "VALUE"


def _examples(para: str) -> list[str]:
    """The command lines of a help paragraph that starts with ``Example`` or ``firmtool``."""
    examples = [ln.strip() for ln in para.strip().splitlines() if ln.strip()]
    if examples[0].rstrip(":") in ("Example", "Examples"):
        examples = examples[1:]
    elif examples[0].startswith("Example:"):
        examples[0] = examples[0][len("Example:"):].strip()
    return examples


def help_markdown(name: str) -> str:
    """A command's usage, description, examples, arguments and options as Markdown (deflists)."""
    cmd = _commands().get(name)
    if cmd is None:
        raise GenerateError(f"no command {name!r}")
    options = [p for p in cmd.params if p.param_type_name == "option" and p.name != "help"]
    arguments = [p for p in cmd.params if p.param_type_name == "argument"]
    usage = " ".join(["[OPTIONS]"] + [p.name.upper() if p.required else f"[{p.name.upper()}]" for p in arguments])
    lines = ["```text", f"firmtool {name} {usage}", "```", ""]
    for para in (cmd.help or "").split("\n\n"):
        text = " ".join(para.split())
        if not text:
            continue
        if text.startswith("Example") or text.startswith("firmtool "):
            examples = _examples(para)
            if examples:
                lines += ["```bash", *examples, "```", ""]
        else:
            lines += [md_escape(text), ""]
    if arguments or options:
        lines += ["**Arguments and options**", ""]
    for p in arguments:
        default = "" if p.required or p.default is None else f" (default: `{p.default}`)"
        lines += [f"`{p.name.upper()}`", f": {md_escape(getattr(p, 'help', '') or '')}{default}", ""]
    for p in options:
        flags = ", ".join(list(p.opts) + list(p.secondary_opts))
        flag = getattr(p, "is_flag", False)
        metavar = "" if flag else " " + _metavar(cmd, p)
        default = ""
        if not flag and p.default is not None and not callable(p.default):
            default = f" (default: `{p.default}`)"
        lines += [f"`{flags}{metavar}`", f": {md_escape(p.help or '')}{default}", ""]
    return "\n".join(lines)


def commands_table(page: Path) -> str:
    """Every command with its first help line and a link to its page ``guide/COMMAND.md``."""
    rows = ["| command | what it does |", "|---|---|"]
    for name, cmd in _commands().items():
        target = DOCS / "guide" / f"{name}.md"
        if not target.exists():
            raise GenerateError(f"the command {name!r} has no page docs/guide/{name}.md")
        first = " ".join((cmd.help or "").split("\n\n")[0].split())
        link = Path(target).relative_to(page.parent) if target.is_relative_to(page.parent) else target
        rows.append(f"| [`firmtool {name}`]({link.as_posix()}) | {md_escape(first)} |")
    return "\n".join(rows) + "\n"


# ---------------------------------------------------------------------------------------------------
# figures, code, the README

def figures_table() -> str:
    """The figures docs/make_figures.py writes, each with what it shows and its command."""
    spec = importlib.util.spec_from_file_location("make_figures", DOCS / "make_figures.py")
    make_figures = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(spec.name, make_figures)  # its dataclasses look their module up
    spec.loader.exec_module(sys.modules[spec.name])
    make_figures = sys.modules[spec.name]
    rows = ["| figure | what | made by |", "|---|---|---|"]
    for fig in make_figures.FIGURES:
        if not (DOCS / "figures" / fig.file).exists():
            raise GenerateError(f"docs/figures/{fig.file} is missing; run python docs/make_figures.py")
        rows.append(f"| `figures/{fig.file}` | {md_escape(fig.what)} | `{fig.command}` |")
    return "\n".join(rows) + "\n"


def _pyobject(text: str, name: str, path: Path) -> str:
    """The source of a top-level class or function (its decorators included)."""
    for node in ast.parse(text).body:
        if isinstance(node, (ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.name == name:
            start = min([node.lineno] + [d.lineno for d in node.decorator_list])
            return "\n".join(text.splitlines()[start - 1:node.end_lineno]) + "\n"
    raise GenerateError(f"{path}: no class or function {name!r}")


def include(page: Path, args: list[str]) -> str:
    """A file's text (or a part of it) as a code block, with a link to the file."""
    rel, options = args[0], dict(a.split("=", 1) for a in args[1:])
    path = (page.parent / rel).resolve()
    if not path.exists():
        raise GenerateError(f"{page.name}: include of a missing file {rel}")
    text = path.read_text()
    if "pyobject" in options:
        text = _pyobject(text, options["pyobject"], path)
    if "start-at" in options:
        at = text.find(options["start-at"])
        if at < 0:
            raise GenerateError(f"{path.name}: no {options['start-at']!r}")
        text = text[text.rfind("\n", 0, at) + 1:]
    if "end-before" in options:
        at = text.find(options["end-before"])
        if at < 0:
            raise GenerateError(f"{path.name}: no {options['end-before']!r}")
        text = text[:text.rfind("\n", 0, at) + 1]
    language = options.get("language", "python" if path.suffix == ".py" else "text")
    what = f"`{options['pyobject']}` in " if "pyobject" in options else ""
    source = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else path.name
    return f"{what}[`{source}`]({rel}):\n\n```{language}\n{text.rstrip()}\n```\n"


def _relink(markdown: str) -> str:
    """README links made relative to docs/: ``docs/x`` -> ``x``, another file of the repository
    ``f`` -> ``../f``; web addresses and anchors unchanged."""
    def fix(m: re.Match) -> str:
        target = m.group(2)
        if re.match(r"[a-z]+://|#|mailto:", target):
            return m.group(0)
        target = target[len("docs/"):] if target.startswith("docs/") else f"../{target}"
        return f"{m.group(1)}({target})"

    return re.sub(r"(\]|\!\[[^\]]*\])\(([^)\s]+)\)", fix, markdown)


def readme_part() -> str:
    """The README up to its ``## Documentation`` section, its links relative to docs/."""
    text = (ROOT / "README.md").read_text()
    end = text.find("\n## Documentation")
    if end < 0:
        raise GenerateError("README.md has no '## Documentation' section")
    return _relink(text[:end].rstrip() + "\n")


# ---------------------------------------------------------------------------------------------------
# the pages

def render_block(page: Path, spec: str) -> str:
    """The text of one generated block, named by its comment's ``spec``."""
    if spec.startswith("api "):
        try:
            return api_markdown.render(spec[4:])
        except api_markdown.ApiError as exc:
            raise GenerateError(f"{page.name}: {exc}") from None
    kind, *args = shlex.split(spec)
    if kind == "help" and len(args) == 1:
        return help_markdown(args[0])
    if kind == "commands" and not args:
        return commands_table(page)
    if kind == "template" and len(args) == 1:
        return f"```toml\n{template('my_scenario', args[0]).rstrip()}\n```\n"
    if kind == "scenario-reference" and not args:
        return reference_markdown(level=2)
    if kind == "figures" and not args:
        return figures_table()
    if kind == "results" and args:
        try:
            return results_numbers.render(args)
        except KeyError as exc:
            raise GenerateError(f"{page.name}: {exc.args[0]}") from None
    if kind == "readme" and not args:
        return readme_part()
    if kind == "include" and args:
        return include(page, args)
    raise GenerateError(f"{page.name}: unknown generated block {spec!r}")


def render_page(page: Path, text: str) -> str:
    """The page's text with each generated block rewritten."""
    def fill(m: re.Match) -> str:
        body = render_block(page, m.group("spec")).rstrip("\n") + "\n"
        return f"{m.group(1)}{body}{m.group(4)}"

    return BLOCK.sub(fill, text)


def pages(root: Path = DOCS) -> list[Path]:
    """The Markdown pages under ``root`` (the build folder left out)."""
    return sorted(p for p in root.rglob("*.md") if "_build" not in p.parts)


def stale(root: Path = DOCS) -> list[Path]:
    """The pages under ``root`` whose generated blocks differ from what this script writes."""
    return [p for p in pages(root) if render_page(p, p.read_text()) != p.read_text()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="list the stale pages and exit 1; write nothing")
    args = parser.parse_args(argv)
    try:
        changed = stale()
    except GenerateError as exc:
        print(f"docs/generate.py: {exc}", file=sys.stderr)
        return 2
    for page in changed:
        if not args.check:
            page.write_text(render_page(page, page.read_text()))
        print(f"{'stale' if args.check else 'wrote'}: {page.relative_to(ROOT)}")
    return 1 if args.check and changed else 0


if __name__ == "__main__":
    sys.exit(main())
