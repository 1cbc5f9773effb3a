"""Quality-assurance pages: one self-contained HTML page (+ JSON) per block, and a zone index.

Modules, one concept each (import the names from the module that defines them):

* :mod:`~towerpipe.products.qa.metrics`: the numbers (inputs read, limits, density, accuracy,
  the edge of the data);
* :mod:`~towerpipe.products.qa.plots`: the figures (block map, density, HAG, tower side views,
  zone map);
* :mod:`~towerpipe.products.qa.pages`: rendering the Jinja2 templates in ``templates/``;
* :mod:`~towerpipe.products.qa.block`: :func:`~towerpipe.products.qa.block.block_report`, the
  page of one block;
* :mod:`~towerpipe.products.qa.neighbourhoods`: the points around each tower (side views);
* :mod:`~towerpipe.products.qa.index`: :func:`~towerpipe.products.qa.index.zone_index`, the
  zone's index page;
* :mod:`~towerpipe.products.qa.browser`: loading pages in headless Chromium (checks, screenshots).
"""
