"""How the site reads scatterlab's docstrings (ADR 0093).

* NumPy-style sections (napoleon's parser) for modules, classes and functions; attribute,
  property and constant docstrings are left as written (napoleon would read a first line
  "Phrase: explanation" as "type: explanation").
* ``|x|`` is the docstrings' notation for an absolute value or a norm, never a reST
  substitution: bars outside inline literals and roles are escaped.
* A reference is resolved as Python resolves the name where the docstring stands: a short
  name (``receiver_factor``) through the namespace of the docstring's module, a name
  re-exported by a package (``analysis.brdf.reduction.fit_forward``) to the object's own
  documented place (``analysis.brdf.reduction.values.fit_forward``), and a name that is
  not in the module's namespace at run time (imported for type checking only, or
  ``Class.attribute`` of a class documented elsewhere) to the one documented object whose
  dotted name ends with it. A name that does not lead to a documented object
  stays a warning (an error in the build).
* A built-in name in an annotation (``-> type``) stays text, as the Python domain leaves a
  built-in it cannot find. It is unlinked before resolution because Sphinx marks every
  annotation reference "specific" (``refspecific`` set, even to False), and a specific
  search for ``type`` would match every documented attribute called ``type``
  (``Option.type``, ``Message.type``) and warn that the reference is ambiguous.
"""

from __future__ import annotations

import builtins
import importlib
import re
import sys
from typing import Any

from sphinx.addnodes import pending_xref
from sphinx.ext.napoleon import Config
from sphinx.ext.napoleon.docstring import NumpyDocstring

NAPOLEON = Config(
    napoleon_google_docstring=False,
    napoleon_numpy_docstring=True,
    # type lines are prose ("array_like, shape (N, H, W)"): text, not references
    napoleon_use_param=False,
    napoleon_use_rtype=False,
    napoleon_custom_sections=[("Attributes", "params_style")],
)

# inline literals and interpreted text (roles) are left alone; bars elsewhere escaped
_LITERAL_OR_ROLE = re.compile(r"(``.+?``|:[\w:]+:`[^`]*`)")


def _escape_bars(line: str) -> str:
    parts = _LITERAL_OR_ROLE.split(line)
    return "".join(p if i % 2 else re.sub(r"(?<!\\)\|", r"\\|", p)
                   for i, p in enumerate(parts))


# directives whose body is not reST (the rest, note:: or seealso::, hold prose)
_RAW_DIRECTIVE = re.compile(r"\.\.\s+(math|code|code-block|highlight)::")


def _opens_raw_block(line: str) -> bool:
    """A paragraph ending in ``::`` (a literal block follows) or a raw directive."""
    text = line.strip()
    if text.startswith(".. "):
        return bool(_RAW_DIRECTIVE.match(text))
    return text.endswith("::")


def _escape_prose(lines: list[str]) -> list[str]:
    """Bars escaped outside literal blocks and maths (what is indented deeper than the
    line that opened such a block is left as written)."""
    out: list[str] = []
    block_indent: int | None = None
    for line in lines:
        indent = len(line) - len(line.lstrip())
        if block_indent is not None and (not line.strip() or indent > block_indent):
            out.append(line)
            continue
        block_indent = indent if _opens_raw_block(line) else None
        out.append(_escape_bars(line))
    return out


def process_docstring(app, what, name, obj, options, lines: list[str]) -> None:
    if what not in ("attribute", "property", "data"):
        lines[:] = NumpyDocstring(lines, NAPOLEON, app, what, name, obj, options).lines()
    lines[:] = _escape_prose(lines)


_MISSING = object()


def _walk(obj: Any, parts: list[str]) -> Any:
    for part in parts:
        obj = getattr(obj, part, _MISSING)
        if obj is _MISSING:
            break
    return obj


def _lookup(path: str, module: str | None, cls: str | None) -> Any:
    """The object ``path`` names where the docstring stands: in its class, its module's
    namespace, else as an absolute dotted path."""
    parts = path.split(".")
    if module in sys.modules:
        scopes = [_walk(sys.modules[module], cls.split("."))] if cls else []
        for scope in [*scopes, sys.modules[module]]:
            obj = _walk(scope, parts)
            if obj is not _MISSING:
                return obj
    for i in range(len(parts), 0, -1):  # the longest importable prefix
        try:
            base = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        return _walk(base, parts[i:])
    return _MISSING


def _documented_name(obj: Any, short: str, objects: dict) -> str | None:
    if hasattr(obj, "__module__") and hasattr(obj, "__qualname__"):
        name = f"{obj.__module__}.{obj.__qualname__}"
        if name in objects:
            return name
    if getattr(obj, "__name__", None) in objects and type(obj).__name__ == "module":
        return obj.__name__
    # a constant: the documented entry of that name whose module holds this very object
    for full in objects:
        if full.rsplit(".", 1)[-1] == short:
            mod, _, attr = full.rpartition(".")
            if mod in sys.modules and getattr(sys.modules[mod], attr, _MISSING) is obj:
                return full
    return None


def _only_documented(path: str, objects: dict) -> str | None:
    """The one documented object whose dotted name ends with ``path`` (a name imported for
    type checking only, ``Class.attribute`` of a class the module does not import)."""
    found = [full for full in objects if full == path or full.endswith(f".{path}")]
    return found[0] if len(found) == 1 else None


def resolve_missing(app, env, node, contnode):
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip("~.")
    domain = env.get_domain("py")
    obj = _lookup(target, node.get("py:module"), node.get("py:class"))
    name = None
    if obj is not _MISSING:
        name = _documented_name(obj, target.rsplit(".", 1)[-1], domain.objects)
    if name is None:
        name = _only_documented(target, domain.objects)
    if name is None or name == target:
        return None
    results = domain.resolve_any_xref(env, node["refdoc"], app.builder, name, node, contnode)
    return results[0][1] if results else None


def unlink_builtins(app, doctree) -> None:
    """Replace each Python reference to a built-in class (``type``, ``int``) by its text;
    a reference written ``.type`` (specific on purpose: the project's first) is kept."""
    for node in list(doctree.findall(pending_xref)):
        if (node.get("refdomain") == "py" and not node.get("refspecific")
                and isinstance(getattr(builtins, node.get("reftarget", ""), None), type)):
            node.replace_self(node.children)


def setup(app):
    app.connect("autodoc-process-docstring", process_docstring)
    app.connect("doctree-read", unlink_builtins)
    app.connect("missing-reference", resolve_missing)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
