"""Quality-assurance pages: one self-contained HTML page (+ JSON) per block, and a zone index.

Modules, one concept each:

* :mod:`~towerpipe.products.qa.metrics`: the numbers (inputs read, limits, density, accuracy,
  the edge of the data);
* :mod:`~towerpipe.products.qa.plots`: the figures (block map, density, HAG, tower side views,
  zone map);
* :mod:`~towerpipe.products.qa.pages`: rendering the Jinja2 templates in ``templates/``;
* :mod:`~towerpipe.products.qa.block`: :func:`block_report`, the page of one block;
* :mod:`~towerpipe.products.qa.index`: :func:`zone_index`, the zone's index page;
* :mod:`~towerpipe.products.qa.browser`: loading pages in headless Chromium (checks, screenshots).
"""

from towerpipe.products.qa.block import block_report, tower_neighbourhoods
from towerpipe.products.qa.index import zone_index
from towerpipe.products.qa.metrics import DEFAULT_LIMITS, load_classified, read_benchmark

__all__ = ["DEFAULT_LIMITS", "block_report", "load_classified", "read_benchmark", "tower_neighbourhoods",
           "zone_index"]
