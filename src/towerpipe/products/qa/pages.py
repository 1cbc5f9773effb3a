"""Rendering the QA pages from the Jinja2 templates shipped in ``towerpipe/products/qa/templates``.

The templates get plain data (the dicts written to the pages' JSON, plus figures as
data URIs or inline SVG) and these filters:

``num(v, digits=1)``
    a number with thin-space thousands, ``–`` for None/NaN, yes/no for booleans;
``pct(v)``
    a share (0–1) as a percentage;
``pretty_json(v)``
    indented JSON (raw metadata, shown folded).
"""

from __future__ import annotations

import functools
import json
import math
import os
from typing import Any

import jinja2
import numpy as np
from markupsafe import Markup

from towerpipe.io.atomic import write_text_atomic


def num(v: Any, digits: int = 1) -> str:
    """A number as the pages show it."""
    if v is None or isinstance(v, jinja2.Undefined) or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}".replace(",", "\u202f")
    if isinstance(v, (float, np.floating)):
        return f"{float(v):,.{digits}f}".replace(",", "\u202f")
    return str(v)


def pct(v: Any, digits: int = 1) -> str:
    """A share (0–1) as ``12.3 %``."""
    return "–" if v is None or isinstance(v, jinja2.Undefined) else f"{num(100.0 * float(v), digits)} %"


def pretty_json(v: Any) -> str:
    return json.dumps(v, indent=1, ensure_ascii=False, default=str)


@functools.cache
def environment() -> jinja2.Environment:
    """The pages' Jinja2 environment (templates from the package, HTML autoescaped).

    Missing keys render empty (``–`` through the filters): pages of older runs lack
    fields that newer ones have (sensor attributes, the model choice).
    """
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("towerpipe.products.qa", "templates"),
        autoescape=jinja2.select_autoescape(["html"]),
        undefined=jinja2.ChainableUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters.update(num=num, pct=pct, pretty_json=pretty_json)
    return env


def render(template: str, out_html: str | os.PathLike[str] | None = None, **context: Any) -> str:
    """Render ``template`` with ``context`` (``svg`` values must be :class:`~markupsafe.Markup`).

    Written atomically to ``out_html`` when given; the HTML is returned.
    """
    env = environment()
    html = env.get_template(template).render(css=Markup(env.loader.get_source(env, "style.css")[0]), **context)
    if out_html is not None:
        write_text_atomic(out_html, html)
    return html
