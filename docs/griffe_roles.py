"""Griffe extension for the docs build: geomopt's docstrings as the API pages show them.

geomopt's NumPy-style sections write ``name : what it is`` on one line (shape, type and
meaning in prose, as gpytoolbox does); griffe would take that prose for a type and print it
verbatim, so each such item is rewritten as ``name`` with the prose as its description.

The docstrings cross-reference with Sphinx roles (``:func:`~geomopt.param.start_map```,
``:class:`Energy```, relative to the module or class they sit in).  Each role is resolved by
importing the target: a documented public object becomes an autorefs link to where it is
defined (``--strict`` then fails if that page does not render it); a private or undocumented
one becomes plain code; a target that does not exist at all is logged as a warning, which
``mkdocs build --strict`` turns into a failure (a stale reference in a docstring).
"""

from __future__ import annotations

import importlib
import inspect
import logging
import re

import griffe

ROLE = re.compile(r":(?:py:)?(func|meth|class|mod|data|attr|obj|exc|const):`(~?)([^`]+)`")
_MISSING = object()
log = logging.getLogger("mkdocs.plugins.geomopt_roles")


def _lookup(path: str):
    """``(object, parent)`` for the dotted ``path`` (modules imported as needed), or _MISSING."""
    parts = path.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        parent = None
        for name in parts[cut:]:
            parent, obj = obj, inspect.getattr_static(obj, name, _MISSING)
            if obj is _MISSING:
                break
        if obj is not _MISSING:
            return obj, parent
    return _MISSING, None


def _public(path: str) -> bool:
    return not any(p.startswith("_") for p in path.split(".")[1:])


def _canonical(obj):
    """Where ``obj`` is documented (its defining module and qualname), or None when the API
    pages do not render it (private, no docstring of its own, or data)."""
    obj = getattr(obj, "__func__", obj)
    if isinstance(obj, property):
        obj = obj.fget
    if inspect.ismodule(obj):
        return obj.__name__ if _public(obj.__name__) else None
    if not (inspect.isclass(obj) or inspect.isfunction(obj)) or not obj.__doc__:
        return None
    qual = obj.__qualname__
    if "<" in qual or any(p.startswith("_") for p in qual.split(".")):
        return None
    if "." in qual:  # a method: documented when its class is
        owner, _ = _lookup(f"{obj.__module__}.{qual.rsplit('.', 1)[0]}")
        documented = owner is not _MISSING and _exported(owner)
    else:
        documented = _exported(obj)
    return f"{obj.__module__}.{qual}" if documented else None


def _exported(obj) -> bool:
    """Whether geomopt or a public module of it lists ``obj`` in its ``__all__``."""
    import sys

    for name, module in list(sys.modules.items()):
        if (name == "geomopt" or name.startswith("geomopt.")) and _public(name):
            if any(inspect.getattr_static(module, n, None) is obj for n in getattr(module, "__all__", ())):
                return True
    return False


def _replace(match, context):
    role, tilde, target = match.groups()
    target = target.strip()
    label = target.split(".")[-1] if tilde else target
    candidates = [target] + [f"{c}.{target}" for c in context]
    for path in candidates:
        obj, parent = _lookup(path)
        if obj is not _MISSING:
            where = _canonical(obj)
            return f"[`{label}`][{where}]" if where else f"`{label}`"
    # attributes set in __init__ or declared as dataclass fields cannot be looked up statically
    return f"`{label}`" if role in ("attr", "data") else None


def _rewrite(text: str, context, where: str) -> str:
    def sub(match):
        out = _replace(match, context)
        if out is None:
            log.warning(f"{where}: the docstring refers to {match.group(0)}, which does not exist")
            return f"`{match.group(3)}`"
        return out

    return ROLE.sub(sub, text)


SECTIONS = ("Parameters", "Returns", "Yields", "Raises", "Attributes", "Other Parameters", "Warns")
_ITEM = re.compile(r"^(?P<name>\*{0,2}[A-Za-z_][\w.]*(?:, \*{0,2}[A-Za-z_][\w.]*)*) : (?P<text>.+)$")


def _items_as_descriptions(text: str) -> str:
    """``name : prose`` items of NumPy sections -> ``name`` + the prose, indented, as the
    description.  A Returns section that starts with plain prose (no ``name :``) gets it as
    one unnamed item (``:`` + the prose, indented, up to the next blank line)."""
    lines = text.split("\n")
    out, section, prose = [], None, False
    for i, line in enumerate(lines):
        stripped = line.strip()
        here = len(line) - len(line.lstrip())
        if stripped in SECTIONS and i + 1 < len(lines) and set(lines[i + 1].strip()) == {"-"}:
            section, indent = stripped, here
        elif section is not None and stripped and not set(stripped) <= {"-"}:
            found = _ITEM.match(stripped) if here == indent else None
            if found:
                out += [" " * here + found["name"], " " * (here + 4) + found["text"]]
                continue
            if section in ("Returns", "Yields") and set(out[-1].strip()) == {"-"}:
                out.append(" " * here + ":")
                prose = True
            if prose:
                line = "    " + line
        prose = prose and bool(stripped)
        out.append(line)
    return "\n".join(out)


class SphinxRoles(griffe.Extension):
    def on_package(self, *, pkg, **kwargs):
        self._walk(pkg)

    def _walk(self, obj):
        if obj.docstring is not None:
            # relative targets: the enclosing class(es), then the module, then its package
            context = [p.path for p in _parents(obj) if p.kind.value in ("class", "module")]
            text = _items_as_descriptions(obj.docstring.value)
            obj.docstring.value = _rewrite(text, context, obj.path)
        for member in obj.members.values():
            if not member.is_alias:
                self._walk(member)


def _parents(obj):
    chain = [obj] if obj.kind.value in ("class", "module") else []
    while obj.parent is not None:
        obj = obj.parent
        chain.append(obj)
    return chain
